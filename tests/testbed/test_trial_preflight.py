"""Every trial runs the controllers' read-only check first (issue 43), on two YuMi
hardware twins behind real sshds: a controller a person left in manual mode, or whose
world zones are not known active since its last restart, refuses ``testbed trial`` and
``testbed protocol`` before step 1 with the check's FAULT lines (exit 1), the run
folder says why (run.json ``refused``, no step, no checkpoint), and nothing moved on
either robot: their request logs hold no write (no program file, no start), their
pushers are where they were. A ready pair passes the check: tests/testbed/
test_controller_states.py's trial asserts run.json ``controllers_checked``.
"""

from __future__ import annotations

import json
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from lab_fixtures import calibrate_exactly, tiny_protocol

from drivers.testing.sshd import sshd_available
from testbed.cli import main
from testbed.experiments.controller_gate import TrialRefused
from testbed.experiments.fleet_config import FleetConfig
from testbed.experiments.protocol import Protocol, load_protocol, run_protocol
from testbed.lab.hardware_twin import HardwareTwinLab
from testbed.records.run_dir import RunDir

pytestmark = [
    pytest.mark.slow,
    pytest.mark.ssh,
    pytest.mark.skipif(not sshd_available(), reason="needs OpenSSH sshd (openssh-server)"),
]

MANUAL = "manual, reduced speed mode (MANR), not automatic"
ZONES_UNKNOWN = "the world zones are not known active"
FACTORY = ("Default User", "robotics")
"""ABB's factory login (every UAS grant): what a person's FlexPendant and RobotStudio have."""


class Lab:
    """The twins, the rewritten fleet (as a file too, for the CLI) and its protocol."""

    def __init__(self, twins: HardwareTwinLab, proto: Protocol, root: Path) -> None:
        self.twins, self.root = twins, root
        self.fleet: FleetConfig = twins.rewrite()
        folder = RunDir(root / "fleet")
        folder.path.mkdir()
        folder.write_config(self.fleet)
        self.config = folder.path / "config.toml"
        self.proto = proto.model_copy(update={"fleet": self.fleet, "algorithms": ["bc"],
                                              "trials": 1, "humans": "scripted"})

    def cabinet(self, host: str, change: dict[str, Any]) -> None:
        """What a person at the robot's cabinet does (the twin's ``/lab/controller``)."""
        req = urllib.request.Request(
            f"{self.twins.hosts[host].controller_lab_url}/lab/controller",
            data=json.dumps(change).encode(), method="POST",
            headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(req, timeout=10):
            pass

    def restart(self, host: str) -> None:
        """A restart from the FlexPendant (the factory login's: every grant)."""
        from abb_robot_client.rws import RWS

        rws = RWS(self.twins.hosts[host].controller_url, *FACTORY)
        try:
            rws._do_post("ctrl?action=restart", {"restart-mode": "restart"})
        finally:
            rws.logout()

    def sizes(self) -> dict[str, int]:
        return {n: h.rws_log.stat().st_size for n, h in self.twins.hosts.items() if h.rws_log}

    def writes_since(self, sizes: dict[str, int]) -> dict[str, list[str]]:
        """Every request but a read each twin served since ``sizes`` (and it served some)."""
        out = {}
        for name, size in sizes.items():
            log = self.twins.hosts[name].rws_log
            assert log is not None
            rows = [json.loads(x) for x in log.read_bytes()[size:].decode().splitlines()]
            assert rows, f"{name}: the trial asked its controller nothing?"
            out[name] = [f"{r['method']} {r['path']}" for r in rows if r["method"] != "GET"]
        return out

    def pushers(self) -> dict[str, dict[str, list[float]]]:
        return {n: h.lab.tcp() for n, h in self.twins.hosts.items()}


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Lab]:
    root = tmp_path_factory.mktemp("gate")
    proto = load_protocol(tiny_protocol(root), check_files=False)
    twins = HardwareTwinLab(proto.fleet, root / "lab", seed=11)
    with twins:
        calibrate_exactly(twins)
        yield Lab(twins, proto, root)


def manual(lab: Lab) -> Callable[[], None]:
    lab.cabinet("yumi-a", {"opmode": "MANR"})
    return lambda: lab.cabinet("yumi-a", {"opmode": "AUTO"})


def zones_unknown(lab: Lab) -> Callable[[], None]:
    """The lab removed tb_zones as the POWER_ON event routine, then restarted: the
    zones' PERS still read 5, but no entry shows them written since the restart."""
    lab.cabinet("yumi-a", {"event_routines": False})
    lab.restart("yumi-a")

    def undo() -> None:
        lab.cabinet("yumi-a", {"event_routines": True})
        lab.restart("yumi-a")
    return undo


@pytest.mark.parametrize(("verb", "state", "words"), [
    ("trial", manual, MANUAL), ("protocol", zones_unknown, ZONES_UNKNOWN)],
    ids=["trial-manual-mode", "protocol-zones-not-known-active"])
def test_a_trial_is_refused_before_step_1_and_nothing_moves(
        lab: Lab, tmp_path: Path, capsys: pytest.CaptureFixture[str], verb: str,
        state: Callable[[Lab], Callable[[], None]], words: str) -> None:
    undo = state(lab)
    try:
        sizes, before = lab.sizes(), lab.pushers()
        if verb == "trial":
            rc = main(["trial", "--config", str(lab.config), "--algorithm", "bc", "--steps",
                       "1", "--humans", "scripted", "--out", str(tmp_path), "--name", "gated"])
            err = capsys.readouterr().err.splitlines()
            assert rc == 1, err
            assert err[0].startswith("testbed trial: refused before its first step: the "
                                     "controllers' check found"), err
            faults = [line for line in err if line.startswith("FAULT")]
            run = RunDir(tmp_path / "gated")
        else:  # what testbed protocol and testbed rehearse run: every run is checked
            with pytest.raises(TrialRefused) as refused:
                run_protocol(lab.proto.model_copy(update={"out": str(tmp_path)}), ask=False)
            faults = refused.value.faults
            run = RunDir(tmp_path / "bc-t0")
        assert faults and all(f.startswith("FAULT yumi-a: ") for f in faults), faults
        assert any(words in f for f in faults), faults
        meta = run.read_meta()
        assert meta["status"] == "refused" and meta["refused"] == faults
        assert not run.state.exists() and not run.summary.exists()
        assert not run.steps.exists() or not run.steps.read_text().strip()
        assert lab.writes_since(sizes) == {"yumi-a": [], "yumi-b": []}  # on either robot
        assert lab.pushers() == before
    finally:
        undo()
