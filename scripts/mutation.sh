#!/usr/bin/env bash
# Mutation testing: do the unit tests notice a change to the code? (docs/notes/tests.md,
# "Tests that can fail"). For each MODULE named (a key of [tool.testbed.mutation] in
# pyproject.toml: allocator, priorities, metrics, frame_classes, wire, yumi_zones), mutmut
# mutates that module's files, runs that module's fast unit tests against each mutant,
# one at a time and niced (a 2-core machine others share), and this prints the score:
# killed / total, and every mutant not killed by name.
#
#   scripts/mutation.sh allocator priorities     # run, then score each
#   DIFF=1 scripts/mutation.sh metrics           # also print each survivor's change
#   SCORE_ONLY=1 scripts/mutation.sh metrics     # the last run's score (./mutants kept)
#   RERUN=1 scripts/mutation.sh metrics          # the last run's survivors only, again
#                                                # (after adding tests; one module)
#
# Needs the dev extra (mutmut). Each module starts from an empty ./mutants (git-ignored),
# which is left behind for `mutmut show NAME` / `mutmut browse`.
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${PYTHON:-.venv/bin/python}"
[ -x "$PY" ] || PY=python3
if [ "$#" -eq 0 ]; then
    sed -n '2,16p' "$0"
    exit 2
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
status=0
for module in "$@"; do
    echo "== $module"
    if [ -z "${SCORE_ONLY:-}" ]; then
        nice -n 10 "$PY" scripts/mutation_run.py "${RERUN:+re}run" "$module" \
            > "mutation-$module.log" 2>&1 \
            || { echo "mutmut failed on $module: see mutation-$module.log"; tail -c 1500 "mutation-$module.log"; echo; status=1; continue; }
    fi
    "$PY" scripts/mutation_run.py score "$module" ${DIFF:+--diff} || status=1
done
exit $status
