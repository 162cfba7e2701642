#!/usr/bin/env bash
# README command 2: set up (test tools, sshd, Xvfb, xdotool included), lint (ruff, and
# lint-imports: the import rules between the rooms, docs/ARCHITECTURE.md), run every test.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh --dev
.venv/bin/ruff check .
.venv/bin/lint-imports --no-cache
exec .venv/bin/python -m pytest "$@"
