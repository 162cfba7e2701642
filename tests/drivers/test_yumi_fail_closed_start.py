"""What the YuMi driver checks before it starts anything, and what its stop may touch
(issue 43, "Fail closed everywhere", and its smaller points).

- Every task it starts (both T_ROB_L and T_ROB_R) must read ``TestbedMotion/
  TB_RAPID_VERSION`` equal to ``controller_state.RAPID_VERSION``, read before EVERY start
  (a person may load another module with a ``main`` between two pushes): unreadable or
  different is refused with one line, nothing uploaded, nothing started.
- The stop touches only a program it started, with no window: the running flag is set
  once ``rws.start`` returned; a stop that comes before that prevents the start.
- The motion timeout scales with the controller's speed ratio (a 10 % run takes ten
  times as long) and the twin's motion obeys the ratio.
- No ``Default User`` fallback: no login is an error naming ``credentials_file``; the
  factory login only by name (``factory-default``) and only against a loopback twin.

Played on the twin controller with our RAPID (``sim_twin.rws``), the driver's client
unchanged over HTTP; the seams are the client's own RWS methods, wrapped to act at the
exact moment (deterministic, no sleeps racing a thread).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from drivers.errors import BackendError
from drivers.yumi.controller_state import RAPID_VERSION
from drivers.yumi.controllers import make_controller
from drivers.yumi.credentials import FACTORY_DEFAULT, FACTORY_LOGIN, RwsLogin, read_login
from drivers.yumi.rws_controller import (
    RwsYumiController,
    controller_info,
    is_loopback,
    scaled_timeout,
)
from drivers.yumi.yumi_controller import ArmPose, Waypoint
from sim_twin.rws import Irc5Controller, RwsServer
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.rws_service import RwsService
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
from sim_twin.yumi_cell import YumiTwinCell

PUSHER_MM = 184.2
HERE = (350.0, 150.0, 120.0)
SLOW_LINE = [Waypoint("move_j", HERE, 150.0), Waypoint("move_l", (350.0, 300.0, 120.0), 20.0)]
"""Seconds of motion at 20 mm/s: a program that is still running when it is stopped."""


@dataclass
class Twin:
    ctrl: Irc5Controller
    install: TestbedInstall
    hook: TestbedRapid
    cell: YumiTwinCell
    lock: threading.Lock
    url: str

    def driver(self, motion_timeout_s: float = 60.0) -> RwsYumiController:
        poses = {u.arm: ArmPose(u.task, u.name, tuple(self.hook.poses.joints(u)),
                                tool_z_mm=PUSHER_MM) for u in YUMI_UNITS}
        return RwsYumiController(self.url, poses, http_timeout_s=20.0,
                                 motion_timeout_s=motion_timeout_s, login=FACTORY_LOGIN)

    def execution(self) -> str:
        return str(self.ctrl.execution_item()["ctrlexecstate"])

    def tip(self, arm: str = "left") -> tuple[float, float, float]:
        with self.lock:
            return self.cell.tcp_xyz()[arm]


@pytest.fixture
def make_twin() -> Iterator[Callable[[float], Twin]]:
    made: list[tuple[RwsServer, YumiTwinCell]] = []

    def make(realtime: float = 0.0) -> Twin:
        cell = YumiTwinCell(3, realtime=realtime)
        lock = threading.Lock()
        hook = TestbedRapid(cell, lock, YUMI_UNITS, pusher_length_mm=PUSHER_MM)
        ctrl = Irc5Controller(units=YUMI_UNITS, poses=hook.poses)
        # the modules of the version this driver expects (the pairing itself: tests/drivers/
        # test_yumi_controller_state.py::test_the_drivers_rapid_version_is_the_modules)
        install = TestbedInstall(ctrl, hook, version=RAPID_VERSION)
        server = RwsServer(RwsService(ctrl, program=install)).start_thread()
        made.append((server, cell))
        return Twin(ctrl, install, hook, cell, lock, server.url)

    yield make
    for server, cell in made:
        server.stop()
        cell.close()


def assert_nothing_sent(t: Twin, push: Callable[[], None], words: str) -> None:
    """``push`` is refused with ``words``; no file, no resetpp, no start reached ``t``."""
    files = {f["_title"]: t.ctrl.files.read(f"$TEMP/{f['_title']}")
             for f in t.ctrl.files.listdir("$TEMP")}
    newest, ran = t.ctrl.elog.newest, t.hook.last_run
    with pytest.raises(BackendError, match=words) as got:
        push()
    assert "the motion was not started" in str(got.value) and "\n" not in str(got.value)
    assert {f["_title"]: t.ctrl.files.read(f"$TEMP/{f['_title']}")
            for f in t.ctrl.files.listdir("$TEMP")} == files
    assert t.ctrl.elog.newest == newest and t.hook.last_run is ran


# -- the RAPID version, of every task, before every start --------------------------------
def test_every_task_must_hold_our_rapid_of_the_expected_version(
        make_twin: Callable[[float], Twin]) -> None:
    t = make_twin(0.0)
    client = t.driver()
    try:
        client.execute({"left": [Waypoint("move_j", HERE, 150.0)]})  # ours: it runs
        # a person loads another program into the right task between two pushes: a step
        # of the LEFT arm alone still starts both tasks, so it is refused
        t.ctrl.symbols.undeclare("T_ROB_R", "TestbedMotion", "TB_RAPID_VERSION")
        assert_nothing_sent(t, lambda: client.execute(
            {"left": [Waypoint("move_j", (340.0, 150.0, 120.0), 150.0)]}),
            r"^YuMi controller: task T_ROB_R: TestbedMotion/TB_RAPID_VERSION cannot be read")
        t.install.set_version(RAPID_VERSION)  # our modules again, both tasks
        t.ctrl.symbols.declare("T_ROB_L", "TestbedMotion", "TB_RAPID_VERSION", "num",
                               str(RAPID_VERSION - 1), "CONST")  # an older one, left only
        assert_nothing_sent(t, lambda: client.execute(  # the left task runs a "stay"
            {"right": [Waypoint("move_j", (350.0, -150.0, 120.0), 150.0)]}),
            rf"task T_ROB_L: TestbedMotion/TB_RAPID_VERSION is {RAPID_VERSION - 1}, this "
            rf"driver needs {RAPID_VERSION}; load robot/rapid/")
        t.install.set_version(RAPID_VERSION)
        client.execute({"left": [Waypoint("move_j", (340.0, 150.0, 120.0), 150.0)]})
    finally:
        client.close()


# -- the stop: only our program, no window -------------------------------------------------
def test_a_stop_during_the_checks_leaves_a_persons_program_running(
        make_twin: Callable[[float], Twin], monkeypatch: pytest.MonkeyPatch) -> None:
    """The flag used to be set before the state check: a stop then ended the person's
    program, which the check was about to refuse."""
    t = make_twin(0.0)
    client = t.driver()
    try:
        t.ctrl.set_state(execution="running")  # started from the FlexPendant
        plain = client._rws.get_execution_state

        def stop_first() -> Any:  # the operator's stop, right inside the state check
            client.stop()
            return plain()

        monkeypatch.setattr(client._rws, "get_execution_state", stop_first)
        with pytest.raises(BackendError, match="RAPID is running"):
            client.execute({"left": [Waypoint("move_j", HERE, 150.0)]})
        time.sleep(0.2)
        assert t.execution() == "running"
    finally:
        client.close()


def test_a_stop_between_the_checks_and_the_start_prevents_the_start(
        make_twin: Callable[[float], Twin], monkeypatch: pytest.MonkeyPatch) -> None:
    t = make_twin(0.0)
    client = t.driver()
    try:
        before, ran = t.tip(), t.hook.last_run
        plain = client._rws.upload_file

        def upload_then_stop(name: str, data: bytes) -> None:  # the last call before start
            plain(name, data)
            if name.endswith("testbed_T_ROB_R.bin"):
                client.stop()

        monkeypatch.setattr(client._rws, "upload_file", upload_then_stop)
        with pytest.raises(BackendError, match=r"stopped before it started.*not started"):
            client.execute({"left": [Waypoint("move_j", (380.0, 150.0, 120.0), 150.0)]})
        assert t.hook.last_run is ran and t.tip() == before  # no program ran, no motion
        assert t.execution() == "stopped"
    finally:
        client.close()


def test_a_stop_while_the_start_is_sent_stops_our_program(
        make_twin: Callable[[float], Twin], monkeypatch: pytest.MonkeyPatch) -> None:
    """The start reached the controller, the flag is not set yet: the stop sends nothing,
    and the driver, seeing the stop once its program is started, stops it itself."""
    t = make_twin(1.0)  # real time: the program is still moving when it is stopped
    client = t.driver()
    try:
        plain = client._rws.start

        def start_then_stop(**kw: Any) -> None:
            plain(**kw)
            client.stop()

        monkeypatch.setattr(client._rws, "start", start_then_stop)
        t0 = time.monotonic()
        with pytest.raises(BackendError, match="the motion was stopped"):
            client.execute({"left": SLOW_LINE})
        assert t.ctrl.wait_stopped(5.0) and time.monotonic() - t0 < 5.0
        assert t.tip()[1] < 290.0  # the line (to y 300) was cut short
    finally:
        client.close()


# -- the motion timeout scales with the speed ratio ----------------------------------------
def test_the_timeout_is_motion_timeout_s_at_the_speed_ratio() -> None:
    assert scaled_timeout(15.0, 100.0) == 15.0
    assert scaled_timeout(15.0, 10.0) == 150.0
    assert scaled_timeout(15.0, 0.0) == 1500.0 and scaled_timeout(15.0, 250.0) == 15.0
    assert scaled_timeout(15.0, None) == 15.0  # an old RobotWare: unscaled


@pytest.mark.slow
def test_a_10_percent_run_finishes_where_the_plain_timeout_would_cut_it(
        make_twin: Callable[[float], Twin]) -> None:
    t = make_twin(10.0)  # ten times real time
    line = [Waypoint("move_l", (350.0, 300.0, 120.0), 100.0)]
    first = t.driver()  # untimed: from rest, and the line at 100 %
    first.execute({"left": [Waypoint("move_j", HERE, 150.0)]})
    t0 = time.monotonic()
    first.execute({"left": line})
    fast = time.monotonic() - t0
    first.close()
    t.ctrl.set_state(speedratio=10)
    client = t.driver(motion_timeout_s=1.0)
    try:
        t0 = time.monotonic()
        client.execute({"left": [Waypoint("move_l", HERE, 100.0)]})  # back, at 10 %
        slow = time.monotonic() - t0
        assert client.timeout_s == pytest.approx(10.0)
        assert slow > 1.0  # motion_timeout_s unscaled would have cut it off
        assert slow > 3 * fast  # the twin obeys the ratio
        assert t.tip() == pytest.approx(HERE, abs=1.0)
    finally:
        client.close()


# -- the login: no Default User fallback ---------------------------------------------------
def test_no_login_is_an_error_naming_credentials_file(tmp_path: Path,
                                                      make_twin: Callable[[float], Twin]
                                                      ) -> None:
    pose = ArmPose("T_ROB_L", "ROB_L", (40, -90, 30, 0, 40, 0, 135), tool_z_mm=PUSHER_MM)
    with pytest.raises(BackendError, match=r"^credentials_file is not set: the YuMi host's "
                                           r"credentials_file must name .*never falls back "
                                           r"to ABB's factory 'Default User'"):
        make_controller("http://127.0.0.1:1", {"left": pose})  # the agent's build
    with pytest.raises(BackendError, match=r"'factory-default' \(ABB's factory login\) is "
                                           r"taken only from the hardware twin"):
        make_controller("http://192.0.2.1", {"left": pose}, credentials_file=FACTORY_DEFAULT)
    assert read_login(FACTORY_DEFAULT) == FACTORY_LOGIN and FACTORY_LOGIN.factory
    assert is_loopback("http://127.0.0.1:80") and is_loopback("http://[::1]:8080")
    assert is_loopback("http://localhost") and not is_loopback("http://yumi.lab")
    assert isinstance(make_controller("http://127.0.0.1:1", {"left": pose},
                                      credentials_file=FACTORY_DEFAULT), RwsYumiController)
    t = make_twin(0.0)  # it would take Default User: none is sent without a file
    assert controller_info(t.url, None) is None
    assert controller_info(t.url, FACTORY_DEFAULT) is not None
    login = tmp_path / "rws.login"
    login.write_text("Default User:robotics\n")  # the factory login, written by the lab
    login.chmod(0o600)
    assert read_login(login) == RwsLogin("Default User", "robotics")  # a file: its choice
    assert controller_info(t.url, str(login)) is not None


def test_an_agent_without_credentials_file_does_not_start(tmp_path: Path) -> None:
    """The error comes at the agent's start (its backend's build), one line naming the
    host's field; a lab's agent never logs in as Default User behind anyone's back."""
    from driver_fakes import local_host, twin_picture, write_video, yumi_calibration

    from drivers.host_fleet import HostFleet
    from testbed.core.host_config import ArmConfig

    video = write_video(tmp_path / "cam.avi", [twin_picture(0)])
    cal = tmp_path / "left.json"
    cal.write_text(json.dumps(yumi_calibration("left")))
    host = local_host("yumi0", backend="yumi", camera=str(video),
                      controller_url="http://127.0.0.1:9",
                      arms=[ArmConfig(name="left", crop=(0, 0, 64, 64), calibration=str(cal))])
    with HostFleet([host]) as fleet:
        st = fleet.host_status()["yumi0"]
    assert not st.connected and "credentials_file is not set" in str(st.error)
    assert "Default User" in str(st.error) and "Traceback" not in str(st.error)
