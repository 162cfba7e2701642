#!/usr/bin/env bash
# README command 1: set up, then run a 250-step twin trial (4 arms on 2 twin hosts,
# 2 scripted humans, C.U.R.) and print its summary. Extra arguments go to `testbed trial`.
# With --dry-run (the plan alone) and a .venv already made, the setup (apt, ~85 s) is
# skipped: the plan needs nothing it installs.
set -euo pipefail
cd "$(dirname "$0")/.."
dry_run=0
for arg in "$@"; do
  [ "$arg" = "--dry-run" ] && dry_run=1
done
if [ "$dry_run" = 0 ] || [ ! -x .venv/bin/testbed ]; then
  scripts/setup.sh
fi
exec .venv/bin/testbed trial "$@"
