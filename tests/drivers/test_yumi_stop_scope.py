"""What the YuMi driver's stop stops: its own program, never one a person started.

An agent is told to stop as it exits when its link closes during a request (a bye whose
rest was refused because RAPID was running, under load past the bye's deadline). Its
stop used to reach the controller whatever ran there, so a program a person had started
from the FlexPendant ended behind their back, and the next push, instead of being
refused with "RAPID is running", ran (tests/testbed/test_controller_states.py met it
once in a loaded suite). Played on the twin controller (``sim_twin.rws``) with our RAPID,
the driver's client unchanged over HTTP.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

from drivers.errors import BackendError
from drivers.yumi.controller_state import RAPID_VERSION
from drivers.yumi.credentials import FACTORY_LOGIN
from drivers.yumi.rws_controller import RwsYumiController
from drivers.yumi.yumi_controller import ArmPose, Waypoint
from sim_twin.rws import Irc5Controller, RwsServer
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.rws_service import RwsService
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
from sim_twin.yumi_cell import YumiTwinCell

PUSHER_MM = 184.2


@pytest.fixture
def twin() -> Iterator[tuple[Irc5Controller, RwsYumiController]]:
    cell = YumiTwinCell(3, realtime=1.0)  # motions take their real time: one can be stopped
    lock = threading.Lock()
    hook = TestbedRapid(cell, lock, YUMI_UNITS, pusher_length_mm=PUSHER_MM)
    ctrl = Irc5Controller(units=YUMI_UNITS, poses=hook.poses)
    install = TestbedInstall(ctrl, hook, version=RAPID_VERSION)  # what the driver expects
    server = RwsServer(RwsService(ctrl, program=install)).start_thread()
    poses = {u.arm: ArmPose(u.task, u.name, tuple(hook.poses.joints(u)), tool_z_mm=PUSHER_MM)
             for u in YUMI_UNITS}
    client = RwsYumiController(server.url, poses, http_timeout_s=20.0, motion_timeout_s=60.0,
                               login=FACTORY_LOGIN)
    try:
        yield ctrl, client
    finally:
        client.close()
        server.stop()
        cell.close()


def execution(ctrl: Irc5Controller) -> Any:
    return ctrl.execution_item()["ctrlexecstate"]


def test_a_stop_with_none_of_our_programs_running_leaves_a_persons_program_running(
        twin: tuple[Irc5Controller, RwsYumiController]) -> None:
    ctrl, client = twin
    ctrl.set_state(execution="running")  # started from the FlexPendant
    client.stop()
    time.sleep(0.2)
    assert execution(ctrl) == "running"
    with pytest.raises(BackendError, match="RAPID is running"):  # our push is refused
        client.execute({"left": [Waypoint("move_j", (350.0, 200.0, 120.0), 150.0)]})
    assert execution(ctrl) == "running"


def test_a_stop_during_our_program_stops_it(
        twin: tuple[Irc5Controller, RwsYumiController]) -> None:
    ctrl, client = twin
    failed: list[BaseException] = []

    def move() -> None:
        try:  # a long, slow line: seconds at 20 mm/s
            client.execute({"left": [Waypoint("move_j", (350.0, 150.0, 120.0), 150.0),
                                     Waypoint("move_l", (350.0, 300.0, 120.0), 20.0)]})
        except BaseException as exc:
            failed.append(exc)

    mover = threading.Thread(target=move)
    mover.start()
    deadline = time.monotonic() + 10.0
    while execution(ctrl) != "running" and time.monotonic() < deadline:
        time.sleep(0.01)
    assert execution(ctrl) == "running"
    client.stop()
    mover.join(10.0)
    assert not mover.is_alive() and execution(ctrl) == "stopped"
    assert failed and "the motion was stopped" in str(failed[0])
