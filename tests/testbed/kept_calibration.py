"""One calibration of the rehearsal lab's four arms per test run, kept for every rehearsal.

Why: ``testbed rehearse`` calibrates every arm with ``testbed calibrate`` against the
twin (about 80 RWS moves through ABB's client, a minute of a rehearsal test) before its
runs, and three test files rehearse the same protocol (``lab_fixtures.tiny_protocol``:
the same hosts, arms and seed, so the same cells and cameras). The product keeps a
calibration that still holds when a rehearsal is run again
(``testbed/lab/rehearsal.py::lab_calibration``: every arm's file re-checked against the
twin's true camera and the arm's facts), so the tests calibrate once: the first that
needs it runs the rehearsal's own calibration (``lab_calibration`` on a lab of the
rehearsal's seed, the agents from a robot host's install as in
``test_rehearsal.py``'s rehearsal), and every rehearsal starts from its files
(:func:`start_from`), as a rehearsal run again does.
``test_rehearsal.py::test_the_rehearsals_calibration_fits_every_arm_within_bounds``
checks that one calibration, end to end.

Shared across pytest-xdist workers: a folder under the run's base temp (each run makes
its own), made under a file lock, keyed by the protocol's text. A calibration that
failed is kept as its message, so every test that needs it fails with it at once.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from host_install import HostVenv, install_build

CALIBRATED = "calibration.json"
"""The lab folder's record that every arm is calibrated (``testbed.lab.rehearsal``)."""


@dataclass(frozen=True)
class KeptCalibration:
    """What the run's one calibration left: its lab folder (``calib/``, the figures,
    ``fleet/config.toml``), every line it said, and each twin's true camera."""

    lab: Path
    said: list[str]
    cameras: dict[str, dict[str, Any]]

    @property
    def figures(self) -> dict[str, dict[str, float]]:
        """Each arm's error against its twin's true camera (``calibration.json``)."""
        figures: dict[str, dict[str, float]] = json.loads((self.lab / CALIBRATED).read_text())
        return figures


def _shared_root(request: pytest.FixtureRequest) -> Path:
    """The run's base temp: shared by the xdist workers of one run, a run's own."""
    base: Path = request.getfixturevalue("tmp_path_factory").getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def kept_calibration(request: pytest.FixtureRequest, protocol: Path) -> KeptCalibration:
    """The run's calibration of ``protocol``'s lab: made by the first caller (under a
    lock the workers share), read by every other."""
    key = hashlib.sha256(protocol.read_bytes()).hexdigest()[:12]
    folder = _shared_root(request) / f"kept-calibration-{key}"
    with open(folder.with_suffix(".lock"), "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not (folder / "done").exists():
                _make(request, protocol, folder)
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    failed = folder / "failed.txt"
    if failed.exists():
        pytest.fail(f"the run's one rehearsal calibration failed:\n{failed.read_text()}")
    return KeptCalibration(folder / "lab", (folder / "said.txt").read_text().splitlines(),
                           json.loads((folder / "cameras.json").read_text()))


def _make(request: pytest.FixtureRequest, protocol: Path, folder: Path) -> None:
    """What ``rehearse`` does before its runs: the lab of the protocol's seed, its fleet
    rewritten and written, every arm calibrated (``lab_calibration``); the agents from a
    robot host's install with this build (``conftest.host_venv``, asked for only here)."""
    from drivers.build_id import build_id
    from testbed.experiments.protocol import load_protocol
    from testbed.lab.hardware_twin import HardwareTwinLab
    from testbed.lab.rehearsal import RehearsalOptions, _rehearsal_fleet, lab_calibration
    from testbed.records.run_dir import RunDir

    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    said: list[str] = []
    try:
        venv: HostVenv = request.getfixturevalue("host_venv")
        install_build(venv, build_id(), folder)
        proto = load_protocol(protocol, check_files=False)
        fleet = _rehearsal_fleet(proto.fleet, RehearsalOptions(protocol))
        lab = HardwareTwinLab(fleet, folder / "lab", seed=proto.seed(0),
                              host_python=str(venv.python))
        with lab:
            fleet = lab.rewrite(fleet)
            fleet_dir = RunDir(folder / "lab" / "fleet")
            fleet_dir.path.mkdir(parents=True, exist_ok=True)
            fleet_dir.write_config(fleet)
            lab_calibration(lab, fleet, fleet_dir.path / "config.toml", said.append)
            cameras = {n: h.lab.camera() for n, h in lab.hosts.items()}
        (folder / "cameras.json").write_text(json.dumps(cameras))
    except BaseException:
        (folder / "failed.txt").write_text("\n".join(said[-40:]) + "\n"
                                           + traceback.format_exc())
        raise
    finally:
        (folder / "said.txt").write_text("\n".join(said) + "\n")
        (folder / "done").touch()


def start_from(kept: KeptCalibration, out: Path) -> None:
    """``out``'s lab folder as a rehearsal's session before left it: every arm's
    calibration file and the figures that say they are all calibrated (nothing else: the
    twins, sshds, logins and theta_0 are the rehearsal's own)."""
    calib = out / "lab" / "calib"
    calib.mkdir(parents=True, exist_ok=True)
    for f in sorted((kept.lab / "calib").glob("*.json")):
        shutil.copyfile(f, calib / f.name)
    shutil.copyfile(kept.lab / CALIBRATED, out / "lab" / CALIBRATED)
