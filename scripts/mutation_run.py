"""Run mutmut on one module of ``[tool.testbed.mutation]`` and print its score.

Why a runner of our own: mutmut 3 reads one ``[tool.mutmut]`` table, but each module has
its own unit tests, and mutmut's stats phase runs every selected test once: pointed at
the whole suite it would take half an hour on this 2-core machine. So this runner loads
mutmut's configuration, narrows ``only_mutate`` and the test selection to one module's
entry, and runs ``mutmut run`` in this process with that configuration (mutmut forks its
workers from here, so they see the same). One module per process, from an empty
``./mutants``: no result of an earlier module's run (another test selection) is reused.

Usage (scripts/mutation.sh calls it): ``python scripts/mutation_run.py run NAME`` then
``python scripts/mutation_run.py score NAME [--diff]``. The score counts a mutant as
killed when a test failed or timed out on it; every other mutant (survived, no test
covered it) is listed by name, and ``--diff`` prints what it changed. An entry may name
``functions``: globs over mutmut's mutant names (``drivers.wire.x_parse_*``); then only
those mutants are run and scored (a module of which one part is under test).
``rerun NAME`` runs only the last run's survivors again, with the tests as they are now.
"""

from __future__ import annotations

import fnmatch
import shutil
import sys
import tomllib
from pathlib import Path
from typing import Any

KILLED = ("killed", "timeout")


def module_entry(name: str) -> dict[str, Any]:
    """The ``[tool.testbed.mutation.NAME]`` table: ``mutate`` (globs) and ``tests``."""
    table = tomllib.loads(Path("pyproject.toml").read_text())["tool"]["testbed"]["mutation"]
    if name not in table:
        raise SystemExit(f"mutation: no module {name!r} in [tool.testbed.mutation] "
                         f"(known: {', '.join(sorted(table))})")
    return table[name]


def configure(name: str) -> None:
    """Narrow mutmut's configuration to one module and its tests."""
    from mutmut import configuration

    entry = module_entry(name)
    cfg = configuration.config()
    cfg.only_mutate = list(entry["mutate"])
    cfg.pytest_add_cli_args_test_selection = list(entry["tests"])


def run(name: str) -> int:
    """``mutmut run`` on one module, one child at a time, from an empty ./mutants."""
    shutil.rmtree("mutants", ignore_errors=True)
    configure(name)
    from mutmut.__main__ import cli

    try:
        cli(["run", "--max-children", "1", *module_entry(name).get("functions", [])])
    except SystemExit as stop:
        return int(stop.code or 0)
    return 0


def not_killed(name: str) -> list[str]:
    """The mutants of the last run of ``name`` that ran and no test killed, by name (not
    the ones a stopped run never reached)."""
    from mutmut.mutation.data import SourceFileMutationData
    from mutmut.stats import status_by_exit_code

    entry = module_entry(name)
    globs = entry.get("functions", ["*"])
    out = []
    for pattern in entry["mutate"]:
        data = SourceFileMutationData(path=pattern)
        data.load()
        out += [key for key, code in data.exit_code_by_key.items()
                if status_by_exit_code[code] not in (*KILLED, "not checked")
                and any(fnmatch.fnmatch(key, g) for g in globs)]
    return sorted(out)


def rerun(name: str) -> int:
    """Run the last run's survivors again (./mutants kept: the tests are copied afresh,
    new tests are added to mutmut's stats): what the tests added since kill."""
    configure(name)
    names = not_killed(name)
    if not names:
        print(f"mutation: {name}: no mutant left to run again")
        return 0
    from mutmut.__main__ import cli

    try:
        cli(["run", "--max-children", "1", *names])
    except SystemExit as stop:
        return int(stop.code or 0)
    return 0


def score(name: str, diff: bool) -> int:
    """Print killed / total per mutated file and the names of the mutants not killed."""
    configure(name)
    from mutmut.mutation.data import SourceFileMutationData
    from mutmut.mutation.diff_apply import get_diff_for_mutant
    from mutmut.stats import status_by_exit_code

    entry = module_entry(name)
    for pattern in entry["mutate"]:
        data = SourceFileMutationData(path=pattern)
        data.load()
        globs = entry.get("functions", ["*"])
        status = {key: status_by_exit_code[code] for key, code in data.exit_code_by_key.items()
                  if any(fnmatch.fnmatch(key, g) for g in globs)}
        if not status:
            print(f"{pattern}: no results (run it first)")
            return 1
        alive = sorted(key for key, state in status.items() if state not in KILLED)
        killed = len(status) - len(alive)
        print(f"{pattern}: {killed}/{len(status)} killed "
              f"({100.0 * killed / len(status):.1f} %), {len(alive)} not killed")
        for key in alive:
            print(f"    {status[key]}: {key}")
            if diff:
                print(get_diff_for_mutant(key, path=pattern))
    return 0


def main(argv: list[str]) -> int:
    """``run NAME``, ``rerun NAME`` or ``score NAME [--diff]``."""
    if len(argv) < 2 or argv[0] not in ("run", "rerun", "score"):
        print(__doc__)
        return 2
    if argv[0] == "run":
        return run(argv[1])
    if argv[0] == "rerun":
        return rerun(argv[1])
    return score(argv[1], "--diff" in argv[2:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
