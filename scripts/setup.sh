#!/usr/bin/env bash
# Set up this checkout on a fresh Debian/Ubuntu machine: system packages (when missing)
# and the Python 3.11 virtual environment in .venv with the project installed.
#   scripts/setup.sh            operator machine: GUI OpenCV (console), web console, twin, SSH
#   scripts/setup.sh --dev      the same plus the test tools (Xvfb, Chromium and its driver)
#   scripts/setup.sh --host     a robot host: headless OpenCV and the YuMi client only
set -euo pipefail
cd "$(dirname "$0")/.."
extras="console,web,yumi"
apt_pkgs=(openssh-client)
case "${1:-}" in
  --dev) extras="console,web,yumi,ray,dev,export"
         apt_pkgs+=(openssh-server xvfb xauth xdotool chromium chromium-driver) ;;
  --host) extras="headless,yumi" ;;
  "") ;;
  *) echo "usage: scripts/setup.sh [--dev|--host]" >&2; exit 2 ;;
esac

missing=()
for p in "${apt_pkgs[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
if [ ${#missing[@]} -gt 0 ]; then
  sudo=""; [ "$(id -u)" -ne 0 ] && sudo="sudo"
  echo "installing system packages: ${missing[*]}" >&2
  $sudo env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

py=""
for c in python3.11 python3; do
  if command -v "$c" >/dev/null && "$c" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
    py="$c"; break
  fi
done
[ -n "$py" ] || { echo "Python 3.11 is required (pybullet ships wheels for 3.11 only)" >&2; exit 2; }
[ -x .venv/bin/python ] || "$py" -m venv .venv
# --no-compile: pip byte-compiles every module it installs (torch alone: 40 s against
# 12 s here); Python compiles the ones a run imports, once, on first import.
pip=(.venv/bin/python -m pip install -q --no-compile --disable-pip-version-check)
# torch first and pinned: a bare "torch" would pull a CUDA build of several GB.
"${pip[@]}" "torch==2.13.0"
# The other OpenCV build must go before this one is installed: both own cv2/.
other="opencv-python-headless"; [ "$extras" = "headless,yumi" ] && other="opencv-python"
.venv/bin/python -m pip uninstall -q -y "$other" >/dev/null 2>&1 || true
"${pip[@]}" -e ".[${extras}]"
