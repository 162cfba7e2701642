"""``scripts/setup.sh`` on a machine without what it needs says how to get it (issue 44).

Why: a stock Ubuntu 22.04 or 24.04 has no Python 3.11 and no venv package for it, and a
new operator met "Python 3.11 is required" with no way forward. The script is run for
real, from a copy in a folder of its own (so it makes no venv in this checkout), with a
PATH whose ``python3.11`` and ``python3`` are stand-ins: one that is not 3.11, one that
is 3.11 but cannot make a venv (its venv package missing). Everything else is the
machine's own (dpkg, the system's /etc/os-release). And ``scripts/trial.sh --dry-run``
skips the setup once the venv is made (a stand-in setup.sh says whether it ran).
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(tmp: Path, python: str) -> subprocess.CompletedProcess[str]:
    (tmp / "scripts").mkdir()
    shutil.copy(ROOT / "scripts" / "setup.sh", tmp / "scripts" / "setup.sh")
    bin_dir = tmp / "bin"
    bin_dir.mkdir()
    for name in ("python3.11", "python3"):
        fake = bin_dir / name
        fake.write_text(python)
        fake.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}:/usr/bin:/bin"}
    return subprocess.run(["bash", str(tmp / "scripts" / "setup.sh")], cwd=tmp, env=env,
                          capture_output=True, text=True, timeout=120)


def _os_release() -> dict[str, str]:
    out = {}
    for line in Path("/etc/os-release").read_text().splitlines():
        key, _, value = line.partition("=")
        out[key] = value.strip('"')
    return out


def test_no_python_3_11_is_one_line_saying_how_to_get_it_here(tmp_path: Path) -> None:
    got = _run(tmp_path, "#!/bin/sh\nexit 1\n")  # a python that is not 3.11
    assert got.returncode == 2, got.stderr
    line = got.stderr.strip().splitlines()[-1]
    osr = _os_release()
    assert line.startswith("Python 3.11 is required (pybullet ships wheels for 3.11 only); "
                           f"on {osr['PRETTY_NAME']}: "), line
    want = {"debian:12": "sudo apt-get install python3.11 python3.11-venv",
            "ubuntu:22.04": "ppa:deadsnakes/ppa", "ubuntu:24.04": "ppa:deadsnakes/ppa"}
    assert want.get(f"{osr['ID']}:{osr.get('VERSION_ID')}", "uv python install 3.11") in line
    assert not (tmp_path / ".venv").exists()


def test_a_python_3_11_without_venv_is_told_to_install_it(tmp_path: Path) -> None:
    # passes the version check (-c ...), fails "-m venv" as Debian's does without
    # python3.11-venv (ensurepip missing)
    got = _run(tmp_path, '#!/bin/sh\n[ "$1" = "-m" ] && exit 1\nexit 0\n')
    assert got.returncode == 2, got.stderr
    assert got.stderr.strip().splitlines()[-1].endswith(
        "cannot make a virtual environment: install its venv package (Debian, Ubuntu: sudo "
        "apt-get install python3.11-venv)"), got.stderr
    assert not (tmp_path / ".venv").exists()


def _trial_sh(tmp: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """``scripts/trial.sh`` copied beside a stand-in setup.sh (it leaves a mark) and,
    when ``tmp/.venv`` exists, a stand-in testbed that says its arguments."""
    (tmp / "scripts").mkdir(exist_ok=True)
    shutil.copy(ROOT / "scripts" / "trial.sh", tmp / "scripts" / "trial.sh")
    setup = tmp / "scripts" / "setup.sh"
    setup.write_text("#!/bin/sh\ntouch setup-ran\nmkdir -p .venv/bin\n"
                     "printf '#!/bin/sh\\necho testbed \"$@\"\\n' > .venv/bin/testbed\n"
                     "chmod +x .venv/bin/testbed\n")
    setup.chmod(0o755)
    return subprocess.run(["bash", str(tmp / "scripts" / "trial.sh"), *args], cwd=tmp,
                          capture_output=True, text=True, timeout=60)


def test_trial_sh_dry_run_skips_the_setup_once_the_venv_is_made(tmp_path: Path) -> None:
    first = _trial_sh(tmp_path, "--dry-run")  # no .venv yet: set up first
    assert first.returncode == 0, first.stderr
    assert (tmp_path / "setup-ran").exists() and first.stdout == "testbed trial --dry-run\n"
    (tmp_path / "setup-ran").unlink()
    again = _trial_sh(tmp_path, "--steps", "5", "--dry-run")
    assert again.returncode == 0, again.stderr
    assert not (tmp_path / "setup-ran").exists()
    assert again.stdout == "testbed trial --steps 5 --dry-run\n"
    real = _trial_sh(tmp_path, "--steps", "5")  # a real trial still sets up
    assert real.returncode == 0 and (tmp_path / "setup-ran").exists()
