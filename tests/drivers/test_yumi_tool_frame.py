"""Issue 35, "the pusher's tool frame comes from the PC and nothing checks it", against
the twin controller over RWS: the lab measures the pusher and sets ``tool_pusher`` (TASK
PERS in TestbedTask_L/_R); the driver reads it.

- Calibration mode: an arm's file without ``tool_z_mm`` takes the controller's
  ``tool_pusher`` z (``drivers/yumi/arm_calibration.py``: ``tool_of``, ``provisional_calibration``),
  and ``testbed calibrate`` writes that value into the saved file
  (``testbed/lab/calibrate.py``: ``with_tool``).
- ``testbed check`` FAULTs a calibration whose ``tool_z_mm`` differs from the
  controller's ``tool_pusher`` by more than 1 mm (our RAPID would refuse every program),
  and passes one within it.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from abb_robot_client.rws import RWS

from drivers.errors import BackendError
from drivers.yumi.arm_calibration import provisional_calibration, tool_of
from drivers.yumi.check_report import controller_report
from drivers.yumi.credentials import FACTORY_DEFAULT, FACTORY_LOGIN
from drivers.yumi.rws_controller import RwsYumiController
from drivers.yumi.yumi_controller import ArmPose
from sim_twin.rws import Irc5Controller, RwsServer
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.rws_service import RwsService
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
from sim_twin.yumi_cell import YumiTwinCell
from testbed.lab.calibrate import with_tool

MEASURED = 186.5
"""What the lab's 4-point TCP method gave for this pusher (not the shipped 184.2)."""
LOAD = "[0.272,[7.5,11.5,53.8],[1,0,0,0],0.0003,0.00032,0.00009]"


@pytest.fixture
def twin() -> Iterator[tuple[str, Any]]:
    """Our RAPID on a twin controller; its URL and the twin's poses."""
    cell = YumiTwinCell(3, realtime=0.0)
    lock = threading.Lock()
    hook = TestbedRapid(cell, lock, YUMI_UNITS)
    ctrl = Irc5Controller(units=YUMI_UNITS, poses=hook.poses)
    server = RwsServer(RwsService(ctrl, program=TestbedInstall(ctrl, hook))).start_thread()
    try:
        yield server.url, hook.poses
    finally:
        server.stop()
        cell.close()


def set_tool(url: str, task: str, z: float) -> None:
    """As a lab does after measuring: tool_pusher's tframe written over RWS."""
    rws = RWS(url)
    mod = f"TestbedTask_{task[-1]}"
    rws.set_rapid_variable(f"{mod}/tool_pusher", f"[TRUE,[[0,0,{z:g}],[1,0,0,0]],{LOAD}]",
                           task)
    assert f"[0,0,{z:g}]" in rws.get_rapid_variable(f"{mod}/tool_pusher", task)


def test_calibration_mode_takes_the_controllers_tool_and_calibrate_saves_it(
        twin: tuple[str, Any], tmp_path: Path) -> None:
    url, _ = twin
    set_tool(url, "T_ROB_L", MEASURED)
    path = tmp_path / "left.json"
    path.write_text(json.dumps({"task": "T_ROB_L",
                                "rest_joints_deg": [40, -90, 30, 0, 40, 0, 135]}))
    z = tool_of(str(path), "left", url, FACTORY_DEFAULT)
    assert z == pytest.approx(MEASURED)
    assert provisional_calibration(str(path), "left", z).tool_z_mm == pytest.approx(MEASURED)
    with pytest.raises(BackendError, match="has no 'tool_z_mm'"):  # never the flange
        provisional_calibration(str(path), "left", None)
    # testbed calibrate: the fit saved with the controller's value, said so
    client = RwsYumiController(url, {"left": ArmPose("T_ROB_L", "ROB_L", (40, -90, 30, 0, 40,
                                                                          0, 135),
                                                     tool_z_mm=MEASURED)},
                               login=FACTORY_LOGIN)
    fleet = SimpleNamespace(describe=lambda host: {"controller": client.describe()})
    said: list[str] = []
    saved = with_tool(fleet, SimpleNamespace(name="yumi-a"), "left",
                      {"homography": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "task": "T_ROB_L"},
                      said.append)
    assert saved["tool_z_mm"] == pytest.approx(MEASURED)
    assert said == [f"tool: tool_z_mm {MEASURED:g} from the controller's tool_pusher (T_ROB_L)"]
    # a file that has it keeps it (and says a FAULT when it is not the controller's)
    said.clear()
    kept = with_tool(fleet, SimpleNamespace(name="yumi-a"), "left",
                     {"task": "T_ROB_L", "tool_z_mm": 184.2}, said.append)
    assert kept["tool_z_mm"] == 184.2
    assert len(said) == 1 and said[0].startswith("FAULT yumi-a: the calibration's tool_z_mm "
                                                 "184.2 is not the controller's tool_pusher")
    assert tool_of(str(tmp_path / "none.json"), "right", url, FACTORY_DEFAULT) == pytest.approx(
        184.2)  # no file yet: the arm's task's (the right one untouched: the shipped value)
    path.write_text(json.dumps({"task": "T_ROB_L", "tool_z_mm": 184.2}))
    assert tool_of(str(path), "left", url, FACTORY_DEFAULT) is None
    client.close()


@pytest.mark.parametrize(("calibrated", "faults"), [(MEASURED + 0.8, False),
                                                     (184.2, True)])
def test_testbed_check_faults_a_tool_z_mm_that_is_not_tool_pushers(
        twin: tuple[str, Any], calibrated: float, faults: bool) -> None:
    url, poses = twin
    set_tool(url, "T_ROB_L", MEASURED)
    set_tool(url, "T_ROB_R", calibrated)  # the right arm agrees: only the left is judged
    arms = {u.arm: ArmPose(u.task, u.name, tuple(poses.joints(u)), tool_z_mm=calibrated)
            for u in YUMI_UNITS}
    client = RwsYumiController(url, arms, login=FACTORY_LOGIN)
    info = {"controller": client.describe(),
            "tool_z": {"T_ROB_L": calibrated, "T_ROB_R": calibrated}}
    lines, bad = controller_report("yumi-a", info)
    client.close()
    mine = [f for f in bad if "T_ROB_L" in f and "tool_pusher" in f]
    assert any(f"tool_pusher tframe [[0,0,{MEASURED:g}]" in line for line in lines), lines
    if faults:
        assert len(mine) == 1, bad
        assert mine[0].startswith(f"task T_ROB_L: the calibration's tool_z_mm {calibrated:g} "
                                  f"is not the controller's tool_pusher ([0,0,{MEASURED:g}]")
    else:
        assert mine == [], bad
    assert not [f for f in bad if "T_ROB_R" in f and "tool_pusher" in f]
