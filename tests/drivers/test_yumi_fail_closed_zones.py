"""The zones count as active only when the event log POSITIVELY shows them written since
the last restart (issue 43, "Fail closed everywhere"), and the driver keeps that proof
while a long trial rolls the log over.

``testbed check`` needs, per task, a restart entry and after it that task's "Testbed
Zones Active" entry; the driver proves the same at its first start and then keeps the
proof while it has seen every entry since (drivers/yumi/zones_proof.py). A log cleared
over RWS (``POST rw/elog?action=clearall``) or rolled over before any proof, a gap in
what the driver saw, or a restart without the entry refuses, with nothing uploaded and
nothing started. The proof passes to the next agent on the same robot host by a file
beside the robot's lock, continued only for the same controller (serial) while the log
still holds the newest entry it recorded, unchanged; anything odd and the log alone must
show it. The rules on hand-made logs first, then on the twin controller with our RAPID
(``sim_twin.rws``), the driver's client unchanged over HTTP.
"""

from __future__ import annotations

import json
import stat
import threading
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import pytest
from event_log_entries import e, on, other, restart

from drivers.errors import BackendError
from drivers.yumi.controller_state import RAPID_VERSION, problems
from drivers.yumi.credentials import FACTORY_LOGIN
from drivers.yumi.rws_controller import RwsYumiController
from drivers.yumi.yumi_controller import ArmPose, Waypoint
from drivers.yumi.zones_proof import (
    PROOF_FORMAT,
    ZonesProof,
    proof_path,
    zones_known,
)
from sim_twin.rws import Irc5Controller, RwsServer
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.rws_service import RwsService
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
from sim_twin.yumi_cell import YumiTwinCell

TASKS = ("T_ROB_L", "T_ROB_R")
PUSHER_MM = 184.2


# -- the rules, on hand-made logs (newest first) -----------------------------------------
def proved_log() -> list[Any]:
    """A restart, motors off (an unrelated entry between), both tasks' entries."""
    return [on(4, "T_ROB_R"), on(3, "T_ROB_L"), e(2, 10010, "Motors OFF state"), restart(1)]


def test_a_proof_holds_across_a_rollover_it_saw_every_entry_of() -> None:
    proof = ZonesProof(TASKS)
    log = proved_log()
    assert proof.read(log) is None  # an unrelated entry between: still proved
    for seq in range(5, 40, 3):  # the log keeps 4 entries: restart and zones roll out
        log = [other(seq + 2), other(seq + 1), other(seq), *log][:4]
        assert proof.read(log) is None, seq
    assert not any(x.code == 10045 for x in log)
    fresh = ZonesProof(TASKS)  # a driver that starts now: the log alone shows nothing
    why = fresh.read(log)
    assert why is not None and why.startswith("task T_ROB_L: the world zones are not known "
                                              "active since the last restart: the event "
                                              "log shows no restart entry")
    assert "restart the controller so tb_zones runs" in why and "'The zones'" in why


@pytest.mark.parametrize("cut", ["cleared", "rolled past"])
def test_a_gap_after_the_proof_forgets_it(cut: str) -> None:
    proof = ZonesProof(TASKS)
    log = proved_log()
    assert proof.read(log) is None
    later = [] if cut == "cleared" else [other(9), other(8), other(7), other(6)]  # 5 missed
    why = proof.read(later)
    assert why is not None and "cleared or rolled over past the entries this driver saw" \
        in why and proof.gap
    assert proof.read(later) is not None  # still refused: nothing new shows it
    again = [on(13, "T_ROB_R"), on(12, "T_ROB_L"), restart(11), *later]
    assert proof.read(again) is None  # a restart that ran tb_zones shows it again


def test_a_restart_after_the_proof_refuses_until_its_zones_entries() -> None:
    proof = ZonesProof(TASKS)
    log = proved_log()
    assert proof.read(log) is None
    log = [restart(5), *log]
    why = proof.read(log)
    assert why is not None and "a restart (event log 10045, seq 5) with no 'Testbed Zones " \
                               "Active' entry with zones 5 after it" in why
    log = [on(7, "T_ROB_L"), e(6, 10011, "Motors ON state"), *log]
    why = proof.read(log)
    assert why is not None and why.startswith("task T_ROB_R:")  # the left one alone: no
    log = [on(8, "T_ROB_R"), *log]
    assert proof.read(log) is None
    assert proof.read([restart(9, 10046), *log]) is not None  # a cold start is one too
    assert proof.read([on(11, "T_ROB_R", 3), on(10, "T_ROB_L"), restart(9, 10046),
                       *log]) is not None  # 3 of 5 zones: not proved


def test_before_any_proof_a_cleared_or_rolled_log_refuses() -> None:
    for log in ([], [other(3), other(2)], [on(4, "T_ROB_R"), on(3, "T_ROB_L"), other(2)]):
        assert ZonesProof(TASKS).read(log) is not None
        assert not zones_known(log, "T_ROB_L")["known"]  # testbed check: not known either
    assert ZonesProof(TASKS).read([restart(2), on(1, "T_ROB_L"), on(0, "T_ROB_R")]) \
        is not None  # entries OLDER than the restart prove nothing


# -- from one agent to the next, by the proof file (hand-made logs) -----------------------
SERIAL = "14000-500000"


def roll(log: list[Any], first: int, n: int, keep: int = 4) -> list[Any]:
    """``log`` after ``n`` more unrelated entries from seq ``first``, the newest ``keep``."""
    return [*(other(s) for s in range(first + n - 1, first - 1, -1)), *log][:keep]


def recorded(path: Path) -> tuple[ZonesProof, list[Any]]:
    """A driver that proved the zones, saw the log roll over them (read by read) and
    recorded its proof in ``path``; the log as it left it (no restart entry left)."""
    proof, log = ZonesProof(TASKS), proved_log()
    assert proof.read(log) is None
    for seq in range(5, 20, 3):
        log = roll(log, seq, 3)
        assert proof.read(log) is None
    assert proof.save(path, SERIAL) and not any(x.code in (10045, 80003) for x in log)
    return proof, log


def test_a_fresh_driver_continues_a_recorded_proof_across_a_rollover(tmp_path: Path) -> None:
    path = tmp_path / "robot.zones.json"
    _, log = recorded(path)
    data = json.loads(path.read_text())
    assert data["serial"] == SERIAL and data["format"] == PROOF_FORMAT
    assert data["restart"] == {"seqnum": 1, "code": 10045, "tstamp": "t1"}
    assert data["tasks"]["T_ROB_L"] == {"state": "proved", "zones": {
        "seqnum": 3, "code": 80003, "tstamp": "t3"}}
    assert data["newest"] == {"seqnum": 19, "code": 10002, "tstamp": "t19"}
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert ZonesProof(TASKS).read(log) is not None  # the log alone shows nothing
    fresh = ZonesProof(TASKS)
    assert fresh.load(path, SERIAL) is None
    assert fresh.read(log) is None  # the recorded newest entry is there: continued
    log = roll(log, 20, 2)
    assert fresh.read(log) is None and fresh.save(path, SERIAL)
    assert json.loads(path.read_text())["newest"]["seqnum"] == 21  # passed on again
    again = ZonesProof(TASKS)
    assert again.load(path, SERIAL) is None and again.read(log) is None


def test_a_recorded_proof_whose_newest_entry_rolled_out_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "robot.zones.json"
    _, log = recorded(path)
    log = roll(log, 20, 4)  # four entries no agent saw: the recorded newest is gone
    fresh = ZonesProof(TASKS)
    assert fresh.load(path, SERIAL) is None
    why = fresh.read(log)
    assert why is not None and fresh.gap and ("cleared or rolled over past the newest entry "
                                              f"the agent before this one recorded ({path})"
                                              in why)
    assert ZonesProof(TASKS).load(path, SERIAL) is None
    assert ZonesProof(TASKS).read([]) is not None  # cleared: the same


def test_a_restart_after_the_record_refuses_until_its_zones_entries(tmp_path: Path) -> None:
    path = tmp_path / "robot.zones.json"
    _, log = recorded(path)
    fresh = ZonesProof(TASKS)
    assert fresh.load(path, SERIAL) is None
    log = [restart(20), *log]  # a restart whose tb_zones did not run (yet)
    why = fresh.read(log)
    assert why is not None and "a restart (event log 10045, seq 20) with no" in why
    log = [on(21, "T_ROB_L"), *log]
    assert (why := fresh.read(log)) is not None and why.startswith("task T_ROB_R:")
    assert fresh.read([on(22, "T_ROB_R"), *log]) is None
    late = ZonesProof(TASKS)  # the record, continued past a restart by a later agent
    assert late.load(path, SERIAL) is None and late.read(log) is not None


def test_a_record_of_another_controller_is_not_continued(tmp_path: Path) -> None:
    path = tmp_path / "robot.zones.json"
    _, log = recorded(path)
    fresh = ZonesProof(TASKS)
    why = fresh.load(path, "14000-500001")
    assert why is not None and "recorded for controller '14000-500000', not '14000-500001'" \
        in why
    assert fresh.read(log) is not None  # from the log alone: nothing shown
    assert fresh.read([on(22, "T_ROB_R"), on(21, "T_ROB_L"), restart(20), *log]) is None


def _edit(key: str, value: Any) -> Any:
    def edit(path: Path) -> None:
        data = json.loads(path.read_text())
        target, name = (data["tasks"]["T_ROB_R"], "zones") if key == "zones_R" else (
            data, key)
        target[name] = value
        path.write_text(json.dumps(data))
    return edit


TAMPERED: dict[str, Any] = {
    "not JSON": lambda p: p.write_text('{"format": "fleet-testbed zones pro'),
    "empty": lambda p: p.write_text(""),
    "another format": _edit("format", "fleet-testbed zones proof 2"),
    "an unknown key": _edit("extra", 1),
    "another count": _edit("count", 3),
    "proved without its zones entry": _edit("zones_R", None),
    "proved without a restart": _edit("restart", None),
    "a seqnum as text": _edit("newest", {"seqnum": "19", "code": 10002, "tstamp": "t19"}),
    "writable by others": lambda p: p.chmod(0o622),
    "a link": lambda p: (p.rename(p.with_suffix(".real")), p.symlink_to(
        p.with_suffix(".real"))),
}


@pytest.mark.parametrize("how", sorted(TAMPERED))
def test_a_tampered_or_corrupt_record_is_not_used(tmp_path: Path, how: str) -> None:
    path = tmp_path / "robot.zones.json"
    _, log = recorded(path)
    TAMPERED[how](path)
    fresh = ZonesProof(TASKS)
    why = fresh.load(path, SERIAL)
    assert why is not None and why.startswith(f"zones proof file {path} not used: "), why
    assert fresh.read(log) is not None and not fresh.gap  # from the log alone: refused


@pytest.mark.parametrize("field", ["newest tstamp", "newest code", "restart"])
def test_a_record_that_does_not_match_the_log_is_not_continued(tmp_path: Path,
                                                               field: str) -> None:
    """The newest entry's number alone is not enough (a wrapped or cleared log numbers
    others so), and an entry the record names that is still in the log must be that
    entry (here: a "restart" that the log shows is the motors-off entry)."""
    path = tmp_path / "robot.zones.json"
    proof, log = ZonesProof(TASKS), proved_log()
    assert proof.read(log) is None and proof.save(path, SERIAL)
    log = roll(log, 5, 2, keep=5)  # the restart rolled out; seq 2 (motors off) is there
    untouched = ZonesProof(TASKS)
    assert untouched.load(path, SERIAL) is None and untouched.read(log) is None
    data = json.loads(path.read_text())
    if field == "restart":
        data["restart"] = {"seqnum": 2, "code": 10045, "tstamp": "t2"}
    else:
        data["newest"]["tstamp" if field == "newest tstamp" else "code"] = \
            "t99" if field == "newest tstamp" else 10002
    path.write_text(json.dumps(data))
    fresh = ZonesProof(TASKS)
    assert fresh.load(path, SERIAL) is None
    assert fresh.read(log) is not None and fresh.gap


# -- on the twin, over HTTP ----------------------------------------------------------------
@dataclass
class Twin:
    ctrl: Irc5Controller
    install: TestbedInstall
    hook: TestbedRapid
    url: str

    def driver(self, state: Path | None = None) -> RwsYumiController:
        """The driver; ``state``: where it records its zones proof (the lock folder)."""
        poses = {u.arm: ArmPose(u.task, u.name, tuple(self.hook.poses.joints(u)),
                                tool_z_mm=PUSHER_MM) for u in YUMI_UNITS}
        return RwsYumiController(self.url, poses, http_timeout_s=20.0, motion_timeout_s=60.0,
                                 login=FACTORY_LOGIN, zones_state_dir=state)

    def restart(self) -> None:
        """A controller restart (POWER_ON runs tb_zones if configured), motors on again."""
        self.ctrl.restart("restart")
        self.ctrl.set_state(ctrlstate="motoron")

    def check_faults(self, client: RwsYumiController) -> list[str]:
        """``testbed check``'s FAULT lines about the zones (describe() + problems())."""
        rep = client.describe()
        return [f for f in problems(rep, list(TASKS)) if "world zones" in f]


@pytest.fixture
def twin() -> Iterator[Twin]:
    cell = YumiTwinCell(3, realtime=0.0)
    lock = threading.Lock()
    hook = TestbedRapid(cell, lock, YUMI_UNITS, pusher_length_mm=PUSHER_MM)
    ctrl = Irc5Controller(units=YUMI_UNITS, poses=hook.poses)
    # the modules of the version this driver expects (the pairing itself: tests/drivers/
    # test_yumi_controller_state.py::test_the_drivers_rapid_version_is_the_modules)
    install = TestbedInstall(ctrl, hook, version=RAPID_VERSION)
    server = RwsServer(RwsService(ctrl, program=install)).start_thread()
    try:
        yield Twin(ctrl, install, hook, server.url)
    finally:
        server.stop()
        cell.close()


def step(x: float) -> dict[str, list[Waypoint]]:
    return {"left": [Waypoint("move_j", (x, 200.0, 120.0), 150.0)]}


def refused_with_nothing_sent(t: Twin, client: RwsYumiController, words: str) -> str:
    """The push is refused with ``words``; nothing reached the controller but reads."""
    newest, ran = t.ctrl.elog.newest, t.hook.last_run
    with pytest.raises(BackendError, match=words) as got:
        client.execute(step(330.0))
    assert t.ctrl.elog.newest == newest and t.hook.last_run is ran  # no resetpp, no run
    assert "the motion was not started" in str(got.value)
    return str(got.value)


def test_a_log_cleared_over_rws_faults_the_check_and_refuses_the_driver(twin: Twin) -> None:
    client = twin.driver()
    try:
        assert twin.check_faults(client) == []
        client.execute(step(350.0))  # proved at the first start
        client._rws._do_post("rw/elog?action=clearall", {})  # RWS "Clear elog messages"
        assert twin.ctrl.elog.entries() == []
        faults = twin.check_faults(client)
        assert len(faults) == 2 and all("holds no restart entry (cleared over RWS, or rolled "
                                        "over)" in f for f in faults), faults
        refused_with_nothing_sent(twin, client, "cleared or rolled over past the entries "
                                                "this driver saw")
        twin.restart()  # the fix the line names
        assert twin.check_faults(client) == []
        client.execute(step(340.0))
    finally:
        client.close()


def test_a_rolled_over_log_after_a_proved_start_goes_on(twin: Twin) -> None:
    twin.ctrl.elog.capacity = 16  # a small elog domain: a few pushes roll it over
    client = twin.driver()
    try:
        for k in range(6):
            client.execute(step(330.0 + 5 * k))
        codes = {x.code for x in twin.ctrl.elog.entries()}
        assert 10045 not in codes and 80003 in codes  # the restart rolled out, pushes done
        assert twin.check_faults(client) == []  # testbed check: the driver's kept proof
        rep = client.describe()["rapid"]["T_ROB_L"]["zones_known"]
        assert rep["known"] and rep["kept"] and rep["zones"] == 5, rep
    finally:
        client.close()
    late = twin.driver()  # a driver that starts now has no proof: faulted and refused
    try:
        faults = twin.check_faults(late)
        assert len(faults) == 2 and all("holds no restart entry" in f for f in faults), faults
        refused_with_nothing_sent(twin, late, "the event log shows no restart entry "
                                              "followed by a 'Testbed Zones Active' entry")
    finally:
        late.close()


def test_a_restart_after_the_proof_refuses_until_tb_zones_writes_again(twin: Twin) -> None:
    client = twin.driver()
    try:
        client.execute(step(350.0))
        twin.install.set_event_routines(False)  # a lab removed tb_zones from POWER_ON
        twin.restart()
        why = refused_with_nothing_sent(twin, client, r"task T_ROB_L: the world zones are not "
                                                      r"known active since the last restart: a "
                                                      r"restart \(event log 10045, seq \d+\) "
                                                      r"with no 'Testbed Zones Active' entry")
        assert "restart the controller so tb_zones runs" in why
        assert len(twin.check_faults(client)) == 2
        twin.install.set_event_routines(True)
        twin.restart()  # 10045, motors off (10010), then both Zones Active entries
        log = twin.ctrl.elog.entries()
        assert [x.code for x in log[:4]] == [10011, 80003, 80003, 10010] and \
            log[4].code == 10045  # an unrelated entry between the restart and the zones
        client.execute(step(340.0))
        assert twin.check_faults(client) == []
    finally:
        client.close()


# -- from one agent to the next, on the twin ------------------------------------------------
def recorded_on_the_twin(t: Twin, state: Path) -> Path:
    """A driver that records its proof in ``state`` proves the zones at its first start
    and pushes until a small log (16 entries) rolled the restart out; its proof file."""
    t.ctrl.elog.capacity = 16
    client = t.driver(state)
    try:
        for k in range(6):
            client.execute(step(330.0 + 5 * k))
    finally:
        client.close()
    assert not any(x.code == 10045 for x in t.ctrl.elog.entries())
    path = proof_path(state, SERIAL)
    assert path.parent == state and path.name.startswith("IRC5_14000-500000-") and \
        path.name.endswith(".zones.json")  # beside the robot's lock (drivers/hostlock.py)
    assert json.loads(path.read_text())["newest"]["seqnum"] == t.ctrl.elog.newest
    return path


def test_a_fresh_driver_goes_on_from_the_recorded_proof_after_a_rollover(
        twin: Twin, tmp_path: Path) -> None:
    recorded_on_the_twin(twin, tmp_path)
    bare = twin.driver()  # no proof file: the log alone shows nothing
    try:
        assert len(twin.check_faults(bare)) == 2
        refused_with_nothing_sent(twin, bare, "the event log shows no restart entry")
    finally:
        bare.close()
    fresh = twin.driver(tmp_path)  # the next trial, or --resume after a crash
    try:  # its check before step 1 continues the proof as its first start would
        assert twin.check_faults(fresh) == []
        fresh.execute(step(350.0))
        fresh.execute(step(345.0))
    finally:
        fresh.close()


def test_a_recorded_proof_rolled_past_or_followed_by_a_bare_restart_refuses(
        twin: Twin, tmp_path: Path) -> None:
    path = recorded_on_the_twin(twin, tmp_path)
    for _ in range(16):  # entries no agent saw roll the recorded newest out
        twin.ctrl.elog.write(10002, 1, "Program pointer has been reset")
    fresh = twin.driver(tmp_path)
    try:
        refused_with_nothing_sent(twin, fresh, "cleared or rolled over past the newest entry "
                                               "the agent before this one recorded")
        twin.restart()  # the fix the line names: proved from the log again, and recorded
        fresh.execute(step(350.0))
    finally:
        fresh.close()
    twin.install.set_event_routines(False)  # a restart that ran no tb_zones
    twin.restart()
    late = twin.driver(tmp_path)
    try:
        refused_with_nothing_sent(twin, late, r"a restart \(event log 10045, seq \d+\) with "
                                              r"no 'Testbed Zones Active' entry")
        twin.install.set_event_routines(True)
        twin.restart()
        late.execute(step(340.0))
    finally:
        late.close()
    assert json.loads(path.read_text())["tasks"]["T_ROB_R"]["state"] == "proved"


def test_another_serial_or_a_corrupt_record_proves_from_the_log_alone(
        twin: Twin, tmp_path: Path) -> None:
    path = recorded_on_the_twin(twin, tmp_path)
    twin.ctrl.identity = replace(twin.ctrl.identity, ctrl_id="14000-500001")
    other_path = proof_path(tmp_path, "14000-500001")
    for copied in (False, True):  # no record of this serial; the other's, copied over
        if copied:
            other_path.write_bytes(path.read_bytes())
            other_path.chmod(0o600)
        client = twin.driver(tmp_path)
        try:
            refused_with_nothing_sent(twin, client, "the event log shows no restart entry")
        finally:
            client.close()
    twin.ctrl.identity = replace(twin.ctrl.identity, ctrl_id=SERIAL)
    path.write_text(path.read_text()[:-20])  # cut short: not JSON
    client = twin.driver(tmp_path)
    try:
        refused_with_nothing_sent(twin, client, "the event log shows no restart entry")
        twin.restart()
        client.execute(step(350.0))  # proved from the log, recorded whole again
    finally:
        client.close()
    assert ZonesProof(TASKS).load(path, SERIAL) is None


# -- what testbed check's report says of the zones (the mutation entry yumi_check) --------
def test_the_kept_proof_in_a_report_names_its_evidence_and_nothing_unproved() -> None:
    proof = ZonesProof(TASKS)
    assert proof.known("T_ROB_L") is None  # nothing read yet
    log = [on(4, "T_ROB_R"), restart(3), on(2, "T_ROB_L"), restart(1)]
    assert proof.read(log) is not None  # T_ROB_L's entry came before the last restart
    assert proof.known("T_ROB_L") is None and proof.known("T_ROB_R") is not None
    assert proof.read([on(5, "T_ROB_L"), *log]) is None
    assert proof.known("T_ROB_L") == {
        "restart": 3, "restart_code": 10045, "active": 5, "zones": 5, "known": True,
        "kept": "the driver's proof, kept across the event log's rollovers"}
    assert proof.known("T_ROB_R")["active"] == 4  # type: ignore[index]
    gone = ZonesProof(TASKS)
    gone.state, gone.active = dict(proof.state), dict(proof.active)  # evidence half lost
    assert gone.known("T_ROB_L") is None
    gone.restart, gone.active["T_ROB_L"] = proof.restart, None
    assert gone.known("T_ROB_L") is None


def test_a_report_reads_the_log_it_is_given_and_names_every_task(twin: Twin) -> None:
    from drivers.yumi.controller_state import describe

    client = twin.driver()
    try:
        rws = client._rws
        log = rws.read_event_log()
        rep = describe(rws, list(TASKS), log)
        assert all(rep.rapid[t]["zones_known"]["known"] for t in TASKS)
        assert rep.serial == SERIAL and rep.robotware
        assert any(o.startswith("623-1") for o in rep.options), rep.options  # Multitasking
        assert describe(rws, list(TASKS)).rapid == rep.rapid  # no log given: read there
        assert rep.state["ctrlstate"] == "motoron"
        for t in TASKS:
            assert rep.tasks[t] == {"type": "norm", "active": True,  # RWS says "norm"
                                    "excstate": rep.tasks[t]["excstate"], "motion": True}
            assert rep.rapid[t]["version"] == RAPID_VERSION
        assert not any(describe(rws, list(TASKS), [])  # an empty log given: not known
                       .rapid[t]["zones_known"]["known"] for t in TASKS)
    finally:
        client.close()
    twin.url = twin.url.replace("http://", "http://127.0.0.2:1/#")  # nothing listens
    broken = twin.driver()
    try:
        with pytest.raises(BackendError, match=r"cannot read the YuMi controller's state: "
                                               r"\S") as got:
            broken.describe()
        assert not str(got.value).endswith("None")  # the client's own words
    finally:
        broken.close()
