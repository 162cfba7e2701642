#!/usr/bin/env bash
# README command 2: set up (test tools, sshd, Xvfb, xdotool included), lint, run every test.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh --dev
.venv/bin/ruff check .
exec .venv/bin/python -m pytest "$@"
