#!/usr/bin/env bash
# Set up this checkout on a fresh Debian/Ubuntu machine: system packages (when missing)
# and a virtual environment with the project installed (docs/setup.md, "Two installs").
#   scripts/setup.sh              operator machine (.venv, Python 3.11): the extra `operator`
#                                 (torch, the twin, SSH, plots), GUI OpenCV (console), web
#                                 console, YuMi clients; editable
#   scripts/setup.sh --dev        the same plus the test tools (sshd, Xvfb, Chromium, driver)
#   scripts/setup.sh --host [DIR] a robot host (DIR, default .venv-host; Python 3.10-3.12):
#                                 the agent's side only, headless OpenCV and the YuMi clients;
#                                 no torch, pybullet, kornia or matplotlib. Installed (not
#                                 editable) from this checkout's stamped wheel; `testbed
#                                 deploy` on the operator's machine replaces it with its build
set -euo pipefail
mode="${1:-}"
host_venv="${2:-.venv-host}"
case "$mode" in
  --host) [ $# -le 2 ] || { echo "usage: scripts/setup.sh --host [DIR]" >&2; exit 2; }
          # DIR as the caller meant it (relative to where they stand), before the cd below
          case "$host_venv" in /*) ;; *) host_venv="$PWD/$host_venv" ;; esac ;;
  --dev|"") [ $# -le 1 ] || { echo "usage: scripts/setup.sh [--dev|--host [DIR]]" >&2; exit 2; } ;;
  *) echo "usage: scripts/setup.sh [--dev|--host [DIR]]" >&2; exit 2 ;;
esac
cd "$(dirname "$0")/.."
extras="operator,console,web,yumi,export"
apt_pkgs=(openssh-client)
case "$mode" in
  --dev) extras="operator,console,web,yumi,ray,dev,export"
         apt_pkgs+=(openssh-server xvfb xauth xdotool chromium chromium-driver iproute2 nginx) ;;
  --host) extras="headless,yumi"
          apt_pkgs=(openssh-server git) ;;  # reached over SSH; git stamps the build
esac

missing=()
for p in "${apt_pkgs[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
if [ ${#missing[@]} -gt 0 ]; then
  sudo=""; [ "$(id -u)" -ne 0 ] && sudo="sudo"
  echo "installing system packages: ${missing[*]}" >&2
  $sudo env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

if [ "$mode" = --host ]; then
  py=""
  for c in python3.12 python3.11 python3.10 python3; do
    if command -v "$c" >/dev/null && "$c" -c 'import sys; sys.exit(not (3, 10) <= sys.version_info[:2] <= (3, 12))'; then
      py="$c"; break
    fi
  done
  [ -n "$py" ] || { echo "a robot host needs Python 3.10, 3.11 or 3.12" >&2; exit 2; }
  [ -x "$host_venv/bin/python" ] || "$py" -m venv "$host_venv"
  hpy="$host_venv/bin/python"
  # A host has no screen: the headless OpenCV, never the GUI build beside it (both own cv2/).
  "$hpy" -m pip uninstall -q -y opencv-python >/dev/null 2>&1 || true
  wheels="$(mktemp -d)"
  trap 'rm -rf "$wheels"' EXIT
  # This checkout's wheel, stamped with its build id (drivers/build_id.py: standard
  # library only, so it runs before anything is installed), then its host extras.
  wheel="$(PYTHONPATH="$PWD" "$hpy" -m drivers.build_id --wheel "$wheels")"
  "$hpy" -m pip install -q --disable-pip-version-check "${wheel}[${extras}]"
  built="$(cd / && "$hpy" -c 'from drivers.build_id import build_id; print(build_id())')"
  echo "robot host ready: build $built in $host_venv" >&2
  echo "in the fleet config, this host's python = \"$hpy\" (and no workdir)" >&2
  exit 0
fi

py=""
for c in python3.11 python3; do
  if command -v "$c" >/dev/null && "$c" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
    py="$c"; break
  fi
done
if [ -z "$py" ]; then
  # where the releases labs use keep it (docs/setup.md, "A fresh operator machine")
  . /etc/os-release 2>/dev/null || true
  case "${ID:-}:${VERSION_ID:-}" in
    debian:12) how="sudo apt-get install python3.11 python3.11-venv" ;;
    ubuntu:22.04|ubuntu:24.04)
      how="sudo add-apt-repository ppa:deadsnakes/ppa && sudo apt-get update && sudo apt-get install python3.11 python3.11-venv" ;;
    *) how="install uv (https://docs.astral.sh/uv/), then: uv python install 3.11 and put its python3.11 on PATH" ;;
  esac
  echo "Python 3.11 is required (pybullet ships wheels for 3.11 only); on ${PRETTY_NAME:-this system}: $how" >&2
  exit 2
fi
if [ ! -x .venv/bin/python ] && ! "$py" -m venv .venv >/dev/null 2>&1; then
  rm -rf .venv
  echo "$py cannot make a virtual environment: install its venv package (Debian, Ubuntu: sudo apt-get install python3.11-venv)" >&2
  exit 2
fi
# --no-compile: pip byte-compiles every module it installs one file at a time (torch
# alone: 40 s against 12 s here); compileall below does it on every core, once.
pip=(.venv/bin/python -m pip install -q --no-compile --disable-pip-version-check)
# torch first and pinned: a bare "torch" would pull a CUDA build of several GB, and so
# does torch==2.13.0 from PyPI itself on Linux. Without an NVIDIA GPU the CPU build comes
# from PyTorch's own CPU index (about 200 MB); where that index cannot be reached (a lab
# mirror, a machine without the internet) the pinned wheel comes from pip's own indexes,
# which such a machine's pip config names.
cpu_index="https://download.pytorch.org/whl/cpu"
if ! command -v nvidia-smi >/dev/null 2>&1 \
   && .venv/bin/python -c "import urllib.request as u; u.urlopen('$cpu_index/torch/', timeout=5)" >/dev/null 2>&1; then
  "${pip[@]}" --index-url "$cpu_index" "torch==2.13.0"
else
  "${pip[@]}" "torch==2.13.0"
fi
# The headless OpenCV must go before the GUI build is installed: both own cv2/.
.venv/bin/python -m pip uninstall -q -y opencv-python-headless >/dev/null 2>&1 || true
"${pip[@]}" -e ".[${extras}]"
# Byte-compile what was installed and this checkout's packages, on every core; a re-run
# compiles only what changed. Without it, wherever PYTHONDONTWRITEBYTECODE is set (this
# machine's environment sets it) Python never writes a .pyc, and every process compiles
# torch, dynamo and sympy from source again: a trial's start took 10.4 s instead of 2.7
# (docs/notes/tests.md). A file that is not Python 3.11 (a package's 3.12-only test
# helper) stays source, as pip leaves it.
.venv/bin/python -m compileall -q -j 0 testbed drivers gui sim_twin \
  "$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')" \
  >/dev/null 2>&1 || true
