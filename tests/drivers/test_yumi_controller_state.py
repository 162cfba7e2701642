"""What the YuMi driver reads of its controller before a push, and how it logs in.

``drivers.yumi.controller_state`` decides from RWS answers whether a program may start
(Auto, motors on, RAPID stopped, no task stopped by a RAPID error) and what ``testbed
check`` must fail on; ``drivers.yumi.credentials`` reads the host's login file. These are
the rules on hand-made answers; the same rules against the RWS twin over HTTP are in
tests/drivers/test_yumi_rws_twin.py.
"""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from drivers.errors import BackendError
from drivers.yumi.controller_state import (
    RAPID_VERSION,
    ControllerState,
    problems,
    rapid_error,
    rapid_of_task,
    refusal,
    version_refusal,
)
from drivers.yumi.credentials import read_login

ROOT = Path(__file__).resolve().parents[2]


def entry(code: int, msgtype: int = 1, title: str = "t", **kw: object) -> SimpleNamespace:
    return SimpleNamespace(code=code, msgtype=msgtype, title=title, seqnum=kw.pop("seq", 1),
                           args=kw.pop("args", []), desc=kw.pop("desc", ""),
                           causes=kw.pop("causes", ""))


def test_the_login_file_must_be_the_owners_alone(tmp_path: Path) -> None:
    f = tmp_path / "rws.login"
    f.write_text("# the lab's RWS user\nlab:se:cret\n")
    f.chmod(0o600)
    login = read_login(f)
    assert (login.user, login.password) == ("lab", "se:cret")
    assert "se:cret" not in repr(login) and "se:cret" not in str(login)
    f.chmod(0o644)
    with pytest.raises(BackendError, match=r"mode 0644 lets other users read .*chmod 600"):
        read_login(f)
    f.chmod(0o400)
    assert read_login(f).user == "lab"
    f.chmod(0o600)
    for bad in ("nocolon\n", ":nouser\n", "a:b\nc:d\n", "\n"):
        f.write_text(bad)
        with pytest.raises(BackendError, match="expected one line USER:PASSWORD"):
            read_login(f)
    with pytest.raises(BackendError, match=r"^credentials_file .*missing.*: cannot read it"):
        read_login(tmp_path / "missing")


def test_a_rapid_error_counts_until_the_program_pointer_is_reset() -> None:
    stop = entry(40223, 3, "Execution error")
    assert rapid_error([stop, entry(10002)]) is stop  # newest first: after the last reset
    assert rapid_error([entry(10002), stop]) is None  # reset since: cleared
    assert rapid_error([entry(80001, 3, "Testbed Motion Failed"), entry(10002)]) is None
    assert rapid_error([entry(10010, 3)]) is None  # not RAPID's or motion's domain
    assert rapid_error([entry(50024, 3, "Corner path failure")]) is not None


@pytest.mark.parametrize(("state", "words"), [
    (ControllerState("MANR", "motoron", "stopped"), "manual, reduced speed mode (MANR)"),
    (ControllerState("AUTO", "motoroff", "stopped"), "motoroff, not motoron"),
    (ControllerState("AUTO", "guardstop", "stopped"), "a guard stop is open"),
    (ControllerState("AUTO", "motoron", "running"), "RAPID is running"),
    (ControllerState("AUTO", "motoron", "stopped", 100.0, "event log 40223 'x': y"),
     "stopped by a RAPID error (event log 40223"),
])
def test_each_state_that_refuses_a_push_says_what_to_fix(state: ControllerState,
                                                          words: str) -> None:
    why = refusal(state)
    assert why is not None and words in why and "\n" not in why


def test_a_ready_controller_refuses_nothing() -> None:
    assert refusal(ControllerState("AUTO", "motoron", "stopped", 100.0)) is None


def _report(**kw: object) -> dict[str, object]:
    rep: dict[str, object] = {
        "options": ["608-1 World Zones", "616-1 PC Interface", "623-1 Multitasking",
                    "604-1 MultiMove Coordinated"],
        "state": {"opmode": "AUTO", "ctrlstate": "motoron", "execstate": "stopped",
                  "speedratio": 100.0, "rapid_error": None},
        "tasks": {"T_ROB_L": {}, "T_ROB_R": {}},
        "rapid": {t: {"version": RAPID_VERSION, "zones": {
            "tb_zone_lo": [0.0, -300.0, 0.0], "tb_zone_hi": [500.0, 300.0, 0.0],
            "tb_zone_z": 80.0, "tb_floor_z": 0.0},
            "zones_active": {"n": 5.0, "of": 5.0, "at": "2026-01-02 03:04:05"}}
            for t in ("T_ROB_L", "T_ROB_R")}}
    rep.update(kw)
    return rep


def test_check_problems_name_what_to_fix() -> None:
    tasks = ["T_ROB_L", "T_ROB_R"]
    assert problems(_report(), tasks, {"T_ROB_L": (10, -200, 400, 200)}) == []
    assert problems(_report(options=["616-1 PC Interface", "623-1 Multitasking",
                                     "604-2 MultiMove Independent"]), tasks) == [
        "RobotWare option 608-1 World Zones is missing: our RAPID (robot/rapid/) needs it "
        "(robot/README.md)"]
    rapid = _report()["rapid"]
    old = {**rapid, "T_ROB_R": {"version": RAPID_VERSION - 1, "zones": {}}}  # type: ignore[dict-item]
    assert problems(_report(rapid=old), tasks) == [
        f"task T_ROB_R: the testbed RAPID modules are version {RAPID_VERSION - 1}, this "
        f"driver needs {RAPID_VERSION}: load robot/rapid/ from this checkout"]
    gone = {**rapid, "T_ROB_L": {"version": None, "zones": {}}}  # type: ignore[dict-item]
    assert "T_ROB_L: the testbed RAPID modules are not loaded" in problems(
        _report(rapid=gone), tasks)[0]
    wide = problems(_report(), tasks, {"T_ROB_R": (10, -200, 600, 200)})
    assert len(wide) == 1 and "reaches outside the world zone box" in wide[0]
    low = problems(_report(), tasks, travel_z={"T_ROB_L": 60.0, "T_ROB_R": 80.0})
    assert low == ["task T_ROB_L: the calibration's z_travel_mm 60 is below the world zone's "
                   "tb_zone_z 80: a travel outside the zone box would stop the arm; raise "
                   "z_travel_mm to 80 or more"]


def test_zones_defined_but_not_active_are_a_fault() -> None:
    """tb_zones_n (TASK PERS in TestbedZones.sys) short of TB_WZ_COUNT: the POWER_ON
    routine failed or never ran; unreadable: the system module is not loaded (issue 29)."""
    tasks = ["T_ROB_L", "T_ROB_R"]
    rapid = _report()["rapid"]
    short = {**rapid, "T_ROB_R": {**rapid["T_ROB_R"],  # type: ignore[index,dict-item]
                                  "zones_active": {"n": 2.0, "of": 5.0, "at": ""}}}
    assert problems(_report(rapid=short), tasks) == [
        "task T_ROB_R: the world zones are NOT active (2 of 5 activated at the last power "
        "on): tb_zones failed or is not the POWER_ON event routine; read the event log, "
        "fix it and restart the controller (robot/README.md, 'The zones')"]
    gone = {**rapid, "T_ROB_L": {**rapid["T_ROB_L"],  # type: ignore[index,dict-item]
                                 "zones_active": {"n": None, "of": None, "at": ""}}}
    assert "TestbedZones.sys is not loaded" in problems(_report(rapid=gone), tasks)[0]


def test_the_drivers_rapid_version_is_the_modules() -> None:
    text = (ROOT / "robot" / "rapid" / "TestbedMotion.mod").read_text()
    m = re.search(r"CONST num TB_RAPID_VERSION := (\d+);", text)
    assert m is not None and int(m.group(1)) == RAPID_VERSION


def test_motion_timeout_defaults_below_the_deadline() -> None:
    from drivers.yumi.yumi_host import YumiHost

    arms = [{"name": "left", "crop": [0, 0, 1, 1], "calibration": "l.json"}]
    host = YumiHost(name="y", camera="0", controller_url="http://192.0.2.1", arms=arms)
    assert (host.deadline_s, host.motion_timeout_s) == (20.0, 15.0)
    host = YumiHost(name="y", camera="0", controller_url="http://192.0.2.1", arms=arms,
                    deadline_s=8)
    assert host.motion_timeout_s == 6.0


class Symbols:
    """``get_rapid_variable`` of a controller holding ``values`` ("module/name", task);
    anything else is RWS's no-such-symbol (an exception). Counts what was asked."""

    def __init__(self, values: dict[tuple[str, str], str]) -> None:
        self.values = values
        self.asked: list[tuple[str, str]] = []

    def get_rapid_variable(self, var: str, task: str) -> str:
        self.asked.append((var, task))
        return self.values[(var, task)]


def test_the_tcp_speed_cap_is_read_and_a_faster_calibration_is_a_fault() -> None:
    """tb_v_tcp_max (each task module's CONST, issue 43): a calibration's max_speed_mm_s
    above it would have every program refused; unreadable (modules older than the cap):
    nothing on the controller bounds a file's speed."""
    rws = Symbols({("TestbedTask_L/tb_v_tcp_max", "T_ROB_L"): "150"})
    assert rapid_of_task(rws, "T_ROB_L")["v_tcp_max"] == 150.0
    assert rapid_of_task(rws, "T_ROB_R")["v_tcp_max"] is None
    tasks = ["T_ROB_L", "T_ROB_R"]
    rapid = _report()["rapid"]
    capped = {t: {**rapid[t], "v_tcp_max": 150.0} for t in tasks}  # type: ignore[index]
    assert problems(_report(rapid=capped), tasks, max_speed={"T_ROB_L": 150.0}) == []
    assert problems(_report(rapid=capped), tasks, max_speed={"T_ROB_R": 400.0}) == [
        "task T_ROB_R: the calibration's max_speed_mm_s 400 is above the controller's "
        "tb_v_tcp_max 150 mm/s: our RAPID refuses every program; lower max_speed_mm_s to "
        "150 or less"]
    old = {**capped, "T_ROB_L": {**capped["T_ROB_L"], "v_tcp_max": None}}
    assert problems(_report(rapid=old), tasks) == [
        "task T_ROB_L: the controller's tb_v_tcp_max (the TCP speed cap, mm/s) cannot be "
        "read: the task module is older than the cap; load robot/rapid/ from this checkout "
        "(robot/README.md, 'Install')"]


def test_the_driver_reads_every_tasks_rapid_version() -> None:
    key = "TestbedMotion/TB_RAPID_VERSION"
    good = {(key, "T_ROB_L"): str(RAPID_VERSION), (key, "T_ROB_R"): str(RAPID_VERSION)}
    rws = Symbols(good)
    assert version_refusal(rws, ["T_ROB_L", "T_ROB_R"]) is None
    assert rws.asked == [(key, "T_ROB_L"), (key, "T_ROB_R")]  # both, every time
    why = version_refusal(Symbols({**good, (key, "T_ROB_R"): "3"}), ["T_ROB_L", "T_ROB_R"])
    assert why == (f"task T_ROB_R: TestbedMotion/TB_RAPID_VERSION is 3, this driver needs "
                   f"{RAPID_VERSION}; load robot/rapid/ from this checkout (robot/README.md, "
                   f"'Install')")
    gone = Symbols({(key, "T_ROB_R"): str(RAPID_VERSION)})
    why = version_refusal(gone, ["T_ROB_L", "T_ROB_R"])
    assert why is not None and why.startswith("task T_ROB_L: TestbedMotion/TB_RAPID_VERSION "
                                              "cannot be read")
    assert version_refusal(Symbols({**good, (key, "T_ROB_L"): "x"}), ["T_ROB_L"]) is not None
