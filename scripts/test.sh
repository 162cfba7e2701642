#!/usr/bin/env bash
# README command 2: set up (test tools, sshd, Xvfb, xdotool included), lint (ruff, and
# lint-imports: the import rules between the rooms, docs/ARCHITECTURE.md), run every test:
# on pytest-xdist workers, one per CPU (TESTBED_TEST_WORKERS: how many; 0: one process),
# a test file to a worker (a module's fixtures, such as a lab of twins, are made once),
# a test marked `alone` with nothing beside it (tests/conftest.py, docs/notes/tests.md).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh --dev
.venv/bin/ruff check .
.venv/bin/lint-imports --no-cache
exec .venv/bin/python -m pytest -n "${TESTBED_TEST_WORKERS:-auto}" --dist loadfile "$@"
