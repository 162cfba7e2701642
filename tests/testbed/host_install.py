"""A robot host's install for the tests: ``scripts/setup.sh --host`` into a venv of its
own (once per session: ``conftest.host_venv``), the build a test wants in it, and what
its own interpreter says from outside any checkout.

Why a real venv: the claim is about what pip puts on a host (no torch, pybullet, kornia
or matplotlib) and about an agent that runs the INSTALLED package, not this checkout on
PYTHONPATH; only a real install into a real venv shows either.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomli_w

from drivers.build_id import build_wheel
from testbed.experiments.fleet_config import FleetConfig

ROOT = Path(__file__).resolve().parents[2]
OPERATOR_ONLY = ("torch", "pybullet", "kornia", "matplotlib")
SETUP_TIMEOUT_S = 900


@dataclass(frozen=True)
class HostVenv:
    path: Path
    setup_s: float
    """How long ``scripts/setup.sh --host`` took (the packages from this machine's pip
    caches and indexes)."""

    @property
    def python(self) -> Path:
        return self.path / "bin" / "python"

    @property
    def site_packages(self) -> Path:
        v = sys.version_info  # the venv is made from this machine's Python 3.11 too
        return self.path / "lib" / f"python{v.major}.{v.minor}" / "site-packages"


def clean_env() -> dict[str, str]:
    """This process's environment without what would point a host's Python at this
    checkout or this venv."""
    return {k: v for k, v in os.environ.items()
            if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}


def make_host_venv(path: Path) -> HostVenv:
    """``scripts/setup.sh --host PATH``, timed; the test fails with its output if it does."""
    t0 = time.monotonic()
    proc = subprocess.run([str(ROOT / "scripts" / "setup.sh"), "--host", str(path)],
                          cwd=path.parent, env=clean_env(), capture_output=True, text=True,
                          timeout=SETUP_TIMEOUT_S, check=False)
    took = time.monotonic() - t0
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    return HostVenv(path, took)


def install_build(venv: HostVenv, build: str, tmp: Path) -> None:
    """This checkout's wheel, stamped ``build``, into the host venv in place of what is
    there (as ``testbed deploy`` does on a host, here without SSH)."""
    wheel = build_wheel(ROOT, tmp / f"wheel-{time.monotonic_ns()}", build)
    proc = subprocess.run([str(venv.python), "-m", "pip", "install", "-q", "--no-deps",
                           "--force-reinstall", "--disable-pip-version-check", str(wheel)],
                          cwd=tmp, env=clean_env(), capture_output=True, text=True,
                          timeout=SETUP_TIMEOUT_S, check=False)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]


def host_python(venv: HostVenv, code: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``python -c CODE`` with the host's interpreter, from ``cwd`` (not the checkout)."""
    return subprocess.run([str(venv.python), "-c", code], cwd=cwd, env=clean_env(),
                          capture_output=True, text=True, timeout=120, check=False)


def installed(venv: HostVenv, cwd: Path) -> dict[str, str]:
    """``pip list`` of the host venv: normalised name -> version."""
    proc = subprocess.run([str(venv.python), "-m", "pip", "list", "--format=json",
                           "--disable-pip-version-check"], cwd=cwd, env=clean_env(),
                          capture_output=True, text=True, timeout=120, check=True)
    return {d["name"].lower().replace("_", "-"): d["version"] for d in json.loads(proc.stdout)}


def _drop_none(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _drop_none(v) for k, v in value.items() if v is not None}
    if isinstance(value, list):
        return [_drop_none(v) for v in value]
    return value


def write_fleet(fleet: FleetConfig, path: Path) -> Path:
    """The fleet as a config file the CLI reads (``--config``)."""
    path.write_text(tomli_w.dumps(_drop_none(fleet.model_dump(mode="json"))))
    return path
