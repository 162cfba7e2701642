"""Issue 35, "a one-arm program can let the other arm replay its old file", on the driver's
side, against a twin controller that omits ``motiontask`` in ``GET rw/rapid/tasks``
(``Irc5Controller(omit_motiontask=True)``; ``python -m sim_twin.yumi_server
--omit-motiontask``; abb_motion_program_exec issue 4).

With that field missing, abb_robot_client's ``get_tasks()`` reads every task as not a
motion task and its ``start(tasks=[...])`` deactivates nothing: a one-arm start (what
``move_tcp`` did for calibration) starts the other task too, and our RAPID there re-runs
the file its RAM disk still holds, perhaps a push, while a person places markers. The
driver now uploads a file to BOTH tasks every time (the idle one a "stay") and activates
both before ``resetpp`` (``drivers/yumi/rws_controller.py``). The second test runs the old
way (a plain start of one task through the unchanged client) on the same controller and
shows the replay, so the first one means something.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from abb_motion_program_exec import abb_motion_program_exec_client as mpe
from driver_fakes import twin_picture, write_video

from drivers.cameras.camera import VideoCaptureCamera
from drivers.yumi.arm_calibration import ArmCalibration
from drivers.yumi.backend import ArmSetup, YumiBackend
from drivers.yumi.credentials import FACTORY_LOGIN
from drivers.yumi.irb14000 import Arm as IrbArm
from drivers.yumi.irb14000_ik import solve_down
from drivers.yumi.rws_controller import RwsYumiController
from drivers.yumi.yumi_controller import ArmPose, Waypoint
from sim_twin.rws import Irc5Controller, RwsServer
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.rws_service import RwsService
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
from sim_twin.sew_angle import arm_angle
from sim_twin.yumi_arms import ArmModel, abb_to_chain
from sim_twin.yumi_cell import YumiTwinCell
from sim_twin.yumi_geometry import REST_JOINTS_DEG, workspace_mm
from testbed.lab.camera_model import PUSH_ARM_ANGLE_DEG

PUSHER_MM = 184.2
OLD_PUSH = [Waypoint("move_j", (400.0, -200.0, 130.0), 150.0),
            Waypoint("move_l", (400.0, -200.0, 90.0), 100.0)]
"""The right arm's last program: up to 130 mm, down to 90 (where it ends). Replayed, the
pusher goes up to 130 and down again."""
MARKER = (300.0, 200.0, 40.0)
"""Where calibration sends the left pusher (inside the left table box)."""


def marker_arm_angle() -> float:
    """The arm angle (a robtarget's ``eax_a``: ABB's, not axis 7's; docs/notes/rws.md,
    "What eax_a means on a YuMi") of the joints the driver plans for the left pusher down
    at :data:`MARKER` from rest, axis 7 at the push's value (testbed/lab/camera_model.py
    ``PUSH_ARM_ANGLE_DEG``): the move the old driver sent, as the controller needs it."""
    rest = abb_to_chain(REST_JOINTS_DEG["left"])
    s = solve_down(IrbArm("left"), MARKER, PUSHER_MM, PUSH_ARM_ANGLE_DEG, current=rest)
    assert s.pose is not None, s
    return arm_angle(ArmModel("left").pose(s.pose.chain_deg))


@dataclass
class Cell:
    ctrl: Irc5Controller
    hook: TestbedRapid
    cell: YumiTwinCell
    lock: threading.Lock
    client: RwsYumiController
    right_z: list[float]

    def right(self) -> tuple[float, float, float]:
        with self.lock:
            return self.cell.tcp_xyz()["right"]


@pytest.fixture
def omitting() -> Iterator[Cell]:
    """Our RAPID on a twin controller that omits ``motiontask``, the driver's client on
    it; the right pusher's height recorded at every sample of every motion."""
    cell = YumiTwinCell(3, realtime=0.0)
    lock = threading.Lock()
    right_z: list[float] = []
    hook = TestbedRapid(cell, lock, YUMI_UNITS, pusher_length_mm=PUSHER_MM,
                        on_frame=lambda: right_z.append(cell.tcp_xyz()["right"][2]))
    ctrl = Irc5Controller(units=YUMI_UNITS, poses=hook.poses, omit_motiontask=True)
    server = RwsServer(RwsService(ctrl, program=TestbedInstall(ctrl, hook))).start_thread()
    poses = {u.arm: ArmPose(u.task, u.name, tuple(hook.poses.joints(u)), tool_z_mm=PUSHER_MM)
             for u in YUMI_UNITS}
    client = RwsYumiController(server.url, poses, http_timeout_s=20.0, motion_timeout_s=60.0,
                               login=FACTORY_LOGIN)
    try:
        assert not any(t.motiontask for t in client._rws.get_tasks().values())
        client.execute({"right": OLD_PUSH})  # the right task's RAM disk: a motion
        assert cell.tcp_xyz()["right"] == pytest.approx((400.0, -200.0, 90.0), abs=1.0)
        yield Cell(ctrl, hook, cell, lock, client, right_z)
    finally:
        client.close()
        server.stop()
        cell.close()


def backend(c: Cell, tmp_path: Path) -> YumiBackend:
    """A ``YumiBackend`` on the client; the left arm's gate joints measured as ``testbed
    calibrate`` does (a MoveJ to the gate's point, the jointtarget read there, back to
    rest: ``drivers/yumi/backend.py``, ``_measure_gate``), the right arm's none (it is
    not moved here)."""
    setups = []
    for u in YUMI_UNITS:
        cal = {"homography": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
               "table_box_mm": list(workspace_mm(c.cell.sides[u.arm])),
               "z_push_mm": 12.0, "z_travel_mm": 80.0, "max_speed_mm_s": 150.0,
               "push_speed_mm_s": 100.0, "tool_z_mm": PUSHER_MM,
               "rest_joints_deg": list(c.hook.arms.rest_joints(u.arm))}
        if u.arm == "left":
            gate = ArmCalibration.from_dict(cal, u.arm).gate_xyz
            c.client.execute({"left": [Waypoint("move_j", gate, 150.0)]})
            cal["gate_joints_deg"] = list(c.client.joints()["left"])
            c.client.execute({"left": [Waypoint("rest", None, 150.0)]})
        setups.append(ArmSetup(u.arm, (0, 0, 64, 64), u.arm == "right",
                               ArmCalibration.from_dict(cal, u.arm)))
    video = write_video(tmp_path / "cam.avi", [twin_picture(0)])
    return YumiBackend(setups, VideoCaptureCamera(str(video)), c.client)


def test_move_tcp_of_one_arm_leaves_the_other_where_it_was(omitting: Cell,
                                                           tmp_path: Path) -> None:
    b = backend(omitting, tmp_path)
    before = omitting.right()
    omitting.right_z.clear()
    assert b.move_tcp("left", MARKER) == pytest.approx(MARKER, abs=1.0)
    assert omitting.right() == pytest.approx(before, abs=0.1)
    assert omitting.right_z and max(abs(z - before[2]) for z in omitting.right_z) <= 0.1
    # the right task ran, and what it ran was the stay (its old file is gone)
    right = omitting.hook.last_run["T_ROB_R"].program
    assert [type(cmd).__name__ for cmd in right.commands] == ["WaitTime"]
    b.close()


def test_the_old_one_task_start_replays_the_other_arms_push(omitting: Cell) -> None:
    """The old way: upload the left file only, ``resetpp``, ``start(tasks=["T_ROB_L"])``
    through the unchanged client: T_ROB_R starts too and replays its push."""
    rws = omitting.client._rws
    before = omitting.right()
    mp = mpe.MotionProgram(tool=mpe.tooldata(True, mpe.pose([0, 0, PUSHER_MM], [1, 0, 0, 0]),
                                             mpe.loaddata(0.272, [7.5, 11.5, 53.8],
                                                          [1, 0, 0, 0], 0, 0, 0)))
    mp.MoveJ(mpe.robtarget(list(MARKER), [0, 0, 1, 0], mpe.confdata(0, 0, 0, 4),
                           [marker_arm_angle()] + [9e9] * 5), mpe.speeddata(150, 100, 1000, 100),
             mpe.fine)
    rws.upload_file("$TEMP/testbed_T_ROB_L.bin", mp.get_program_bytes(seqno=9))
    omitting.right_z.clear()
    rws.resetpp()
    rws.start(cycle="once", tasks=["T_ROB_L"])
    while rws.get_execution_state().ctrlexecstate == "running":
        threading.Event().wait(0.01)
    assert omitting.hook.last_run["T_ROB_R"].program.seqno != 9  # the old file, replayed
    assert max(omitting.right_z) == pytest.approx(130.0, abs=1.0)  # up and down again
    assert omitting.right() == pytest.approx(before, abs=1.0)
