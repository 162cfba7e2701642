#!/usr/bin/env bash
# README command 1: set up, then run a 250-step twin trial (4 arms on 2 twin hosts,
# 2 scripted humans, C.U.R.) and print its summary. Extra arguments go to `testbed trial`.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
exec .venv/bin/testbed trial "$@"
