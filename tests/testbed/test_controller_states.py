"""A YuMi controller that is not ready, as the lab meets it: ``testbed check`` fails with
one line naming what to fix, and a trial's push on that host faults its arms with that
line (no traceback); the other host goes on.

One hardware-twin lab (2 YuMi hosts, each a ``python -m sim_twin.yumi_server`` behind a
real sshd): the agent runs the real controller client over the twin's Robot Web
Services. The twin's controller is put into each state through its side channel
(``POST /lab/controller``), what a person at the cabinet does with the key switch, the
motors-on button, a door of the cell or the FlexPendant. And a trial's run.json names
each host's controller as the twin reports itself, never its login.
"""

from __future__ import annotations

import json
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from lab_fixtures import calibrate_exactly, tiny_protocol

from drivers.testing.sshd import sshd_available
from drivers.yumi.controller_state import RAPID_VERSION
from testbed.core.types import Fault, PushResult
from testbed.experiments.fleet_config import FleetConfig
from testbed.experiments.protocol import load_protocol
from testbed.lab.hardware_twin import HardwareTwinLab
from testbed.lab.preflight import preflight

pytestmark = [
    pytest.mark.slow,
    pytest.mark.ssh,
    pytest.mark.skipif(not sshd_available(), reason="needs OpenSSH sshd (openssh-server)"),
]

READY = {"opmode": "AUTO", "ctrlstate": "motoron", "execution": "stopped"}


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[HardwareTwinLab, Path]]:
    root = tmp_path_factory.mktemp("states")
    proto = load_protocol(tiny_protocol(root), check_files=False)
    twin_lab = HardwareTwinLab(proto.fleet, root / "lab", seed=5)
    with twin_lab:
        calibrate_exactly(twin_lab)
        yield twin_lab, root


def cabinet(lab: HardwareTwinLab, host: str, change: dict[str, Any]) -> dict[str, Any]:
    """What a person at the robot's cabinet does (the twin controller's side channel)."""
    req = urllib.request.Request(f"{lab.hosts[host].controller_lab_url}/lab/controller",
                                 data=json.dumps(change).encode(), method="POST",
                                 headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=10) as resp:
        out: dict[str, Any] = json.loads(resp.read() or b"{}")
        return out


def pp_to_main(lab: HardwareTwinLab, host: str) -> None:
    """The FlexPendant's "PP to Main" after a RAPID error: a program pointer reset."""
    from abb_robot_client.rws import RWS

    user, password = lab.hosts[host].login_file.read_text().strip().split(":", 1)
    rws = RWS(lab.hosts[host].controller_url, user, password)
    try:
        rws.resetpp()
    finally:
        rws.logout()


def check(fleet: FleetConfig, tmp: Path) -> tuple[bool, list[str]]:
    lines: list[str] = []
    ok = preflight(fleet, tmp / "mosaic.png", lines.append)
    return ok, lines


def test_check_reports_a_ready_controller(lab: tuple[HardwareTwinLab, Path],
                                          tmp_path: Path) -> None:
    twin_lab, _ = lab
    ok, lines = check(twin_lab.rewrite(), tmp_path)
    text = "\n".join(lines)
    assert ok, text
    assert "yumi-a: controller YUMI_TWIN serial 14000-" in text and "RobotWare 6." in text
    assert "mode AUTO, motoron, RAPID stopped, speed ratio 100 %" in text
    assert "608-1 World Zones" in text and "T_ROB_L (active" in text
    v = RAPID_VERSION
    assert f"T_ROB_R: testbed RAPID version {v} (this checkout: {v}); world zone box" in text
    assert "testbed:" not in text and not any(line.startswith("FAULT") for line in lines)


STATES = [
    ("manual", {"opmode": "MANR"}, "manual, reduced speed mode (MANR), not automatic"),
    ("motors-off", {"ctrlstate": "motoroff"}, "the controller state is motoroff"),
    ("guard-stop", {"ctrlstate": "guardstop"}, "a guard stop is open"),
    ("running", {"execution": "running"}, "RAPID is running"),
    ("rapid-error", {"task_error": {"task": "T_ROB_L", "code": 40223,
                                    "title": "Execution error",
                                    "desc": "Task T_ROB_L: the division by zero"}},
     "stopped by a RAPID error (event log 40223 'Execution error'"),
]


@pytest.mark.parametrize(("name", "change", "words"), STATES, ids=[s[0] for s in STATES])
def test_a_controller_not_ready_fails_check_and_faults_only_its_hosts_arms(
        lab: tuple[HardwareTwinLab, Path], tmp_path: Path, name: str,
        change: dict[str, Any], words: str) -> None:
    from drivers.host_fleet import HostFleet

    twin_lab, _ = lab
    fleet = twin_lab.rewrite()
    cabinet(twin_lab, "yumi-a", change)
    try:
        ok, lines = check(fleet, tmp_path)
        faults = [line for line in lines if line.startswith("FAULT")]
        assert not ok and len(faults) == 1, lines
        assert faults[0].startswith("FAULT yumi-a: ") and words in faults[0]
        # A trial started anyway: its push on yumi-a faults both arms with that line.
        with HostFleet(fleet.hosts) as hosts:
            hosts.observe()
            res = hosts.execute({r: 0 for r in hosts.robot_names}, [])
        for arm in ("left", "right"):
            f = res[f"yumi-a/{arm}"]
            assert isinstance(f, Fault) and words in f.reason and "\n" not in f.reason
            assert "Traceback" not in f.traceback
            assert isinstance(res[f"yumi-b/{arm}"], PushResult)  # the other robot pushed
    finally:
        cabinet(twin_lab, "yumi-a", READY)
        if name == "rapid-error":
            pp_to_main(twin_lab, "yumi-a")
    ok, lines = check(fleet, tmp_path)
    assert ok, lines  # fixed at the cabinet: ready again


def test_a_trial_records_each_controller_as_it_says_and_never_its_login(
        lab: tuple[HardwareTwinLab, Path], tmp_path: Path) -> None:
    """run.json ``hosts``: each YuMi host over SSH with the build its agent reported and
    its controller as the twin says over RWS (the ``--serial`` it was started with, its
    RobotWare); no file of the run folder holds the password of a login file. And
    ``controllers_checked``: both passed the read-only check every trial runs first
    (refusals: tests/testbed/test_trial_preflight.py)."""
    from abb_robot_client.rws import RWS

    from drivers.build_id import matches
    from testbed.experiments.trial import TrialOptions, run_trial

    twin_lab, _ = lab
    twin_lab.reset_all()  # the drills above may have left a cube out
    fleet = twin_lab.rewrite()
    # the expert row: no learner to build (no torch); a YuMi has no expert, it pushes 0
    opts = TrialOptions(algorithm="bc", steps=1, seed=5, out=str(tmp_path / "runs"),
                        humans="scripted", name="provenance", evaluate=True, expert=True)
    run, summary = run_trial(fleet, opts)
    assert summary["status"] == "complete"
    meta = json.loads((run.path / "run.json").read_text())
    # the controllers' read-only check ran before step 1, and both passed it
    checked = meta["controllers_checked"]
    assert checked["hosts"] == ["yumi-a", "yumi-b"] and 0 < checked["seconds"] < 60
    hosts = meta["hosts"]
    assert list(hosts) == ["yumi-a", "yumi-b"]
    passwords = []
    for name, twin in twin_lab.hosts.items():
        user, password = twin.login_file.read_text().strip().split(":", 1)
        passwords.append(password)
        rws = RWS(twin.controller_url, user, password)  # what the controller says
        try:
            ident = rws._do_get("ctrl/identity")["_embedded"]["_state"][0]
            system = next(i for i in rws._do_get("rw/system")["_embedded"]["_state"]
                          if i["_type"] == "sys-system-li")
        finally:
            rws.logout()
        assert ident["ctrl-id"] == twin_lab._serial(name)  # its --serial
        entry = hosts[name]
        assert entry == {"backend": "yumi", "transport": "ssh", "build": entry["build"],
                         "arms": ["left", "right"],
                         "controller": {"robotware": system["rwversion"],
                                        "serial": ident["ctrl-id"],
                                        "system": system["name"]}}
        assert matches(entry["build"])
        assert f"build {entry['build']}" in (run.path / "hosts" / f"{name}.log").read_text()
    files = [f for f in run.path.rglob("*") if f.is_file()]
    assert len(files) > 5 and all(len(pw) >= 16 for pw in passwords)
    leaked = [str(f) for f in files for pw in passwords if pw.encode() in f.read_bytes()]
    assert leaked == []
