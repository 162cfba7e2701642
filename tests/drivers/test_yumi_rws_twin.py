"""The agent's real YuMi controller client (``RwsYumiController``) against the RWS twin
serving a real ``YumiTwinCell`` with OUR RAPID's semantics (``TestbedRapid``): a two-arm
step uploads one file per task and moves BOTH arms to their own targets (the library's
naming put both programs in one file and the left arm ran the right's), a one-arm step
moves only that arm, and a refusal of our RAPID reaches the caller as one line naming the
event-log entry."""

from __future__ import annotations

import re
import struct
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from drivers.errors import BackendError
from drivers.yumi.credentials import FACTORY_LOGIN
from drivers.yumi.gate import model_gate_joints
from drivers.yumi.reach import ARM_ANGLE_DEG, ArmTool
from drivers.yumi.rws_controller import RwsYumiController
from drivers.yumi.yumi_controller import ArmPose, Waypoint
from sim_twin.rws import Irc5Controller, RwsServer, serve
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.motion_exec import CellMotion
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
from sim_twin.yumi_arms import rest_tip
from sim_twin.yumi_cell import YumiTwinCell

PUSHER_MM = 184.2
"""The shipped pusher (the twin's and tool_pusher's)."""
REST_TIP = {side: rest_tip(side, PUSHER_MM) for side in ("left", "right")}
"""Where the twin's arms rest the pusher's tip (their rest joints, the pusher)."""
ARM_ANGLE = dict(ARM_ANGLE_DEG)
"""The calibrations' ``arm_angle_deg``, the shipped ones (drivers/yumi/reach.py
``ARM_ANGLE_DEG``): ABB's arm angle every robtarget's joints are solved at and sent with
(drivers/yumi/line_plan.py)."""
LEFT, RIGHT = (400.0, 200.0, 60.0), (420.0, -180.0, 40.0)
Made = tuple[RwsYumiController, Irc5Controller, YumiTwinCell, CellMotion, threading.Lock]


@pytest.fixture
def yumi() -> Iterator[Callable[..., Made]]:
    made: list[tuple[RwsServer, YumiTwinCell, RwsYumiController]] = []

    def make(hook: type[CellMotion] = TestbedRapid) -> Made:
        cell = YumiTwinCell(3, realtime=0.0)
        lock = threading.Lock()
        motion = hook(cell, lock, YUMI_UNITS, pusher_length_mm=PUSHER_MM)
        ctrl = Irc5Controller(units=YUMI_UNITS, poses=motion.poses, on_start=motion)
        if isinstance(motion, TestbedRapid):  # our modules loaded: tool_pusher, the zones
            TestbedInstall(ctrl, motion)
        server = serve(ctrl)
        poses = {u.arm: ArmPose(u.task, u.name, tuple(motion.poses.joints(u)),
                                arm_angle_deg=ARM_ANGLE[u.arm], tool_z_mm=PUSHER_MM)
                 for u in YUMI_UNITS}
        client = RwsYumiController(server.url, poses, http_timeout_s=20.0, login=FACTORY_LOGIN,
                                   motion_timeout_s=60.0)
        made.append((server, cell, client))
        return client, ctrl, cell, motion, lock

    yield make
    for server, cell, client in made:
        client.close()
        server.stop()
        cell.close()


def tcps(cell: YumiTwinCell, lock: threading.Lock) -> dict[str, tuple[float, float, float]]:
    with lock:
        return cell.tcp_xyz()


HIGH_MM = 120.0
"""Where :func:`to`'s joint move ends: well above the zones' 80 mm (from rest a joint move
to a point at 80 mm swings the pusher's tip through the zone outside the table box on
the way: the driver's own programs leave rest by MoveAbsJ to the measured gate joints)."""


def to(xyz: tuple[float, float, float]) -> list[Waypoint]:
    above = (xyz[0], xyz[1], xyz[2] + 40.0)
    return [Waypoint("move_j", (xyz[0], xyz[1], HIGH_MM), 150.0, fine=False),
            Waypoint("move_l", above, 150.0), Waypoint("move_l", xyz, 150.0)]


def test_a_two_arm_step_moves_each_arm_to_its_own_target(yumi: Any) -> None:
    client, ctrl, cell, motion, lock = yumi()
    client.execute({"left": to(LEFT), "right": to(RIGHT)})
    assert sorted(f["_title"] for f in ctrl.files.listdir("$TEMP")) == [
        "testbed_T_ROB_L.bin", "testbed_T_ROB_R.bin"]  # two files: no clash
    assert {t: tp.path for t, tp in motion.last_run.items()} == {
        "T_ROB_L": "RAMDISK:/testbed_T_ROB_L.bin", "T_ROB_R": "RAMDISK:/testbed_T_ROB_R.bin"}
    got = tcps(cell, lock)
    assert got["left"] == pytest.approx(LEFT, abs=1.0)
    assert got["right"] == pytest.approx(RIGHT, abs=1.0)
    # read with tool_pusher, whose tframe each program set: the pusher's tip, not the flange
    assert client.tcp_xyz()["left"] == pytest.approx(LEFT, abs=1.0)
    done = [e for e in ctrl.elog.entries() if e.title == "Testbed Motion Done"]
    assert sorted(e.args[1] for e in done) == ["T_ROB_L", "T_ROB_R"]
    assert {e.args[2] for e in done} == {"seqno 1"}
    client.execute({arm: [Waypoint("move_l", (*xyz[:2], HIGH_MM), 150.0),  # the next step:
                          Waypoint("rest", None, 150.0)]  # seqno 2, back the way it came
                    for arm, xyz in (("left", LEFT), ("right", RIGHT))})
    got = tcps(cell, lock)
    assert got["left"] == pytest.approx(REST_TIP["left"], abs=1.0)
    assert got["right"] == pytest.approx(REST_TIP["right"], abs=1.0)


def test_a_one_arm_step_moves_only_that_arm(yumi: Any) -> None:
    client, ctrl, cell, motion, lock = yumi()
    before = tcps(cell, lock)
    client.execute({"right": to(RIGHT)})
    # both tasks get a file and run it (issue 35: no stale program ever): the idle left
    # one a "stay" (a single WaitTime), which moves nothing
    assert sorted(motion.last_run) == ["T_ROB_L", "T_ROB_R"]
    assert [type(c).__name__ for c in motion.last_run["T_ROB_L"].program.commands] == [
        "WaitTime"]
    got = tcps(cell, lock)
    assert got["right"] == pytest.approx(RIGHT, abs=1.0)
    assert got["left"] == before["left"]
    assert ctrl.task("T_ROB_L").active is True  # activated by the driver, then resetpp


def test_a_malformed_program_is_one_line_naming_the_entry(
        yumi: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    client, _, cell, _, lock = yumi()
    before = tcps(cell, lock)
    plain = client.program

    class Garbled:  # the first command's opcode (float 1 + header) made 99
        def __init__(self, mp: Any) -> None:
            self.mp = mp

        def get_program_bytes(self, seqno: int | None = None) -> bytes:
            data = self.mp.get_program_bytes(seqno)
            i = 4 * (1 + 19 + 25 + 11 + 9 + 1 + 1 + 1)
            return data[:i] + struct.pack("<f", 99.0) + data[i + 4:]

    monkeypatch.setattr(client, "program", lambda arm, wps: Garbled(plain(arm, wps)))
    with pytest.raises(BackendError) as info:
        client.execute({"left": to(LEFT)})
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith("YuMi controller: event log 80001 'Testbed Motion Failed': ")
    assert "Invalid motion program command; RAMDISK:/testbed_T_ROB_L.bin; unknown opcode 99" \
        in msg
    assert tcps(cell, lock) == before


def test_a_target_below_the_table_is_refused_before_any_motion(yumi: Any) -> None:
    client, _, cell, _, lock = yumi()
    before = tcps(cell, lock)
    with pytest.raises(BackendError, match=r"^YuMi controller: event log 80001 'Testbed "
                                           r"Motion Failed': Target below the table; "
                                           r"RAMDISK:/testbed_T_ROB_R.bin; MoveL cmd_num 3: "
                                           r"z -5 mm"):
        client.execute({"left": to(LEFT), "right": to((400.0, -200.0, -5.0))})
    got = tcps(cell, lock)
    assert got["right"] == before["right"]  # refused in full: not even the MoveJ
    assert got["left"] == pytest.approx(LEFT, abs=1.0)  # an independent task: it ran


def test_a_controller_without_our_rapid_is_named(yumi: Any) -> None:
    """Issue 43: the library's RAPID (no TestbedMotion) is refused BEFORE anything is
    uploaded or started (it used to be named only after its run failed); and our RAPID
    that ends without its Done entry is named after the run."""
    client, ctrl, *_ = yumi(hook=CellMotion)  # the library's RAPID: it reads another file
    newest = ctrl.elog.newest
    with pytest.raises(BackendError, match=r"task T_ROB_L: TestbedMotion/TB_RAPID_VERSION "
                                           r"cannot be read: .*the motion was not started"):
        client.execute({"left": to(LEFT)})
    assert ctrl.files.listdir("$TEMP") == [] and ctrl.elog.newest == newest  # nothing sent
    client, ctrl, *_ = yumi()
    ctrl.on_start = None  # RAPID that ends at once and writes nothing
    with pytest.raises(BackendError, match=r"task\(s\) T_ROB_L, T_ROB_R ended without the "
                                           r"event log entry "
                                           r"'Testbed Motion Done' for program 1: is the "
                                           r"testbed RAPID \(robot/rapid/\) loaded"):
        client.execute({"left": to(LEFT)})


# -- the pusher, not the flange: lift first; world zones -----------------------------------
def backend_on(client: RwsYumiController, motion: CellMotion, tmp_path: Path, *,
               table_box: tuple[float, float, float, float] | None = None,
               arm: str | None = None) -> Any:
    """A ``YumiBackend`` on the real client (a video file for a camera: no pictures are
    taken here). Its calibration: the pusher's length as ``tool_z_mm``, the twin's rest,
    and the gate joints as ``testbed calibrate`` measures them:
    the arm sent to the gate's point by a MoveJ (the controller's own solution), its
    jointtarget read there, then back to rest (``drivers/yumi/backend.py``,
    ``_measure_gate``). ``table_box``: the box of arm ``arm`` (the other arm keeps its
    workspace). The homography maps the 64 x 64 crop onto the box (a push at the crop's
    centre is at the box's)."""
    from driver_fakes import twin_picture, write_video

    from drivers.cameras.camera import VideoCaptureCamera
    from drivers.yumi.arm_calibration import ArmCalibration
    from drivers.yumi.backend import ArmSetup, YumiBackend
    from sim_twin.yumi_geometry import workspace_mm

    setups = []
    for u in YUMI_UNITS:
        box = list(table_box if table_box and u.arm == arm
                   else workspace_mm(motion.cell.sides[u.arm]))
        cal = {"homography": [[(box[2] - box[0]) / 64.0, 0, box[0]],  # the crop onto the
                              [0, (box[3] - box[1]) / 64.0, box[1]], [0, 0, 1]],  # box
               "table_box_mm": box,
               "z_push_mm": 12.0, "z_travel_mm": 80.0, "max_speed_mm_s": 150.0,
               "push_speed_mm_s": 100.0, "tool_z_mm": PUSHER_MM,
               "arm_angle_deg": ARM_ANGLE[u.arm],
               "rest_joints_deg": list(motion.arms.rest_joints(u.arm))}
        gate = ArmCalibration.from_dict(cal, u.arm).gate_xyz
        client.execute({u.arm: [Waypoint("move_j", gate, 150.0)]})
        cal["gate_joints_deg"] = list(client.joints()[u.arm])
        client.execute({u.arm: [Waypoint("rest", None, 150.0)]})
        setups.append(ArmSetup(u.arm, (0, 0, 64, 64), u.arm == "right",
                               ArmCalibration.from_dict(cal, u.arm)))
    video = write_video(tmp_path / "cam.avi", [twin_picture(0)])
    return YumiBackend(setups, VideoCaptureCamera(str(video)), client)


def rest_of(setup: Any) -> list[float]:
    return list(setup.calibration.pose.rest_joints_deg)


def names(motion: CellMotion, task: str = "T_ROB_L") -> list[str]:
    """The commands of ``task``'s latest program as our RAPID read them."""
    return [type(c).__name__ for c in motion.last_run[task].program.commands]


def joints_of(cmd: Any) -> list[float]:
    """A MoveAbsJ's joint target, ABB's order (axes 1-6, then axis 7: eax_a)."""
    j = cmd.to_joint_pos
    return [*j.robax, j.extax[0]]


def test_move_tcp_and_rest_lift_the_pusher_first_when_it_is_low(yumi: Any,
                                                                 tmp_path: Path) -> None:
    client, _, cell, motion, lock = yumi()
    backend = backend_on(client, motion, tmp_path)
    cal = backend._arms["left"].calibration
    gate, gate_joints = cal.gate_xy, list(cal.gate_joints_deg)
    low = (400.0, 200.0, 15.0)
    assert backend.move_tcp("left", low) == pytest.approx(low, abs=1.0)
    # from rest: MoveAbsJ to the measured gate joints, never a MoveJ (issue 43)
    cmds = motion.last_run["T_ROB_L"].program.commands
    assert names(motion) == ["MoveAbsJ", "MoveL", "MoveL"]
    assert joints_of(cmds[0]) == pytest.approx(gate_joints, abs=1e-3)
    # The pusher is 15 mm over the table, its flange 199 mm: only a read with the pusher's
    # tool sees that it is low. The rest move goes straight up to travel height first
    # (retracing the way down), straight to the gate's point, MoveAbsJ to the gate joints
    # (the correction), MoveAbsJ to rest (drivers/yumi/paths.py).
    backend.rest()
    cmds = motion.last_run["T_ROB_L"].program.commands
    assert names(motion) == ["MoveL", "MoveL", "MoveAbsJ", "MoveAbsJ"]
    assert list(cmds[0].to_point.trans) == pytest.approx([400.0, 200.0, 80.0], abs=0.05)
    assert list(cmds[1].to_point.trans) == pytest.approx([*gate, 100.0], abs=1e-3)
    assert joints_of(cmds[2]) == pytest.approx(gate_joints, abs=1e-3)
    assert joints_of(cmds[3]) == pytest.approx(cal.pose.rest_joints_deg, abs=1e-3)  # type: ignore[union-attr]
    assert tcps(cell, lock)["left"] == pytest.approx(REST_TIP["left"], abs=1.0)
    assert client.joints()["left"] == pytest.approx(cal.pose.rest_joints_deg, abs=0.01)  # type: ignore[union-attr]
    backend.move_tcp("left", low)
    backend.move_tcp("left", (300.0, 100.0, 20.0))  # from low to another point: up first,
    cmds = motion.last_run["T_ROB_L"].program.commands  # to the gate joints, on from there
    assert names(motion) == ["MoveL", "MoveL", "MoveAbsJ", "MoveL", "MoveL"]
    assert list(cmds[0].to_point.trans) == pytest.approx([400.0, 200.0, 80.0], abs=0.05)
    assert list(cmds[1].to_point.trans) == pytest.approx([*gate, 100.0], abs=1e-3)
    assert joints_of(cmds[2]) == pytest.approx(gate_joints, abs=1e-3)
    assert tcps(cell, lock)["left"] == pytest.approx((300.0, 100.0, 20.0), abs=1.0)
    backend.close()


@pytest.mark.slow  # the push's lines planned: about 6 s
def test_a_push_program_is_moveabsj_to_the_gate_joints_first_and_ends_at_rest(
        yumi: Any, tmp_path: Path) -> None:
    """Issue 43, "the path swept is the path run": the program a push sends, as our
    RAPID read it off the RAM disk: the measured gate joints by MoveAbsJ (the joint move
    testbed check sweeps, no configuration left to the controller), the straight legs,
    straight back to the gate's point, the correction to the gate joints, rest."""
    from drivers.yumi.arm_place import JOINT_TOLERANCE_DEG
    from drivers.yumi.backend import plan_push

    client, _, cell, motion, lock = yumi()
    backend = backend_on(client, motion, tmp_path)
    setup = backend._arms["left"]
    wps = plan_push(setup, (0.5, 0.5), 0.0, 3)
    backend._move({"left": wps})
    cmds = motion.last_run["T_ROB_L"].program.commands
    assert names(motion) == ["MoveAbsJ", "MoveL", "MoveL", "MoveL", "MoveL", "MoveL",
                             "MoveAbsJ", "MoveAbsJ"]
    gate = list(setup.calibration.gate_joints_deg or ())
    assert joints_of(cmds[0]) == pytest.approx(gate, abs=1e-3)
    assert joints_of(cmds[6]) == pytest.approx(gate, abs=1e-3)
    # Issue 43: each MoveL's eax_a is ABB's arm angle of the joints the driver planned
    # for it (drivers/yumi/line_plan.py), by the twin's own arm angle (written apart:
    # sim_twin/sew_angle.py) within 0.1 deg; not axis 7's value (the MoveAbsJ's eax_a)
    from drivers.yumi.gate import arm_tool
    from drivers.yumi.line_plan import planned_targets
    from sim_twin.sew_angle import arm_angle as twin_arm_angle
    from sim_twin.yumi_arms import ArmModel

    tool = arm_tool("left", setup.calibration)
    assert tool is not None
    plan, why = planned_targets(tool, None, rest_of(setup), wps)
    assert why is None
    sent = [c.to_point.extax[0] for c in cmds[1:6]]
    for eax_a, target in zip(sent, plan[1:6], strict=True):
        assert eax_a == pytest.approx(target.arm_angle_deg, abs=1e-3)
        angle = twin_arm_angle(ArmModel("left").pose(target.chain_deg))
        assert abs((eax_a - angle + 180.0) % 360.0 - 180.0) < 0.1
        assert abs(eax_a - target.chain_deg[2]) > 5.0  # the arm angle, not axis 7's value
    rest = list(setup.calibration.pose.rest_joints_deg)  # type: ignore[union-attr]
    assert joints_of(cmds[7]) == pytest.approx(rest, abs=1e-3)
    assert client.joints()["left"] == pytest.approx(rest, abs=JOINT_TOLERANCE_DEG)
    assert tcps(cell, lock)["left"] == pytest.approx(REST_TIP["left"], abs=1.0)
    backend.close()


def test_an_arm_at_an_unknown_pose_is_refused_before_anything_is_sent(
        yumi: Any, tmp_path: Path) -> None:
    """An arm a person jogged somewhere (here: axis 1 swung 20 deg from rest, the
    pusher's tip still high and behind the table) is not at rest, nor at the gate, nor
    on a leg: the driver refuses with the arm, its joints and the fix, and the controller
    hears nothing: no upload, no start, no entry in its event log."""
    client, ctrl, _, motion, _ = yumi()
    backend = backend_on(client, motion, tmp_path)
    rest = list(backend._arms["left"].calibration.pose.rest_joints_deg)  # type: ignore[union-attr]
    jogged = [rest[0] - 20.0, *rest[1:]]
    client.execute({"left": [Waypoint("abs_j", None, 150.0, joints_deg=tuple(jogged))]})
    assert client.joints()["left"] == pytest.approx(jogged, abs=0.01)
    files = {f["_title"]: ctrl.files.read(f"$TEMP/{f['_title']}")
             for f in ctrl.files.listdir("$TEMP")}
    newest = ctrl.elog.newest
    with pytest.raises(BackendError, match=r"^arm left is where the driver will not move it "
                                           r"from: joints \[20\.0, -90\.0, 30\.0, 0\.0, 40\.0, "
                                           r"0\.0, 135\.0\] deg, .*nothing was sent: jog it to "
                                           r"rest on the FlexPendant \(manual reduced speed\), "
                                           r"then PP to Main$"):
        backend.rest()
    with pytest.raises(BackendError, match=r"^arm left is where the driver will not move"):
        backend.move_tcp("left", (300.0, 200.0, 40.0))
    assert ctrl.elog.newest == newest  # no resetpp, no start, no motion: nothing at all
    assert {f["_title"]: ctrl.files.read(f"$TEMP/{f['_title']}")
            for f in ctrl.files.listdir("$TEMP")} == files  # nothing uploaded
    client.execute({"left": [Waypoint("rest", None, 150.0)]})  # the person's jog to rest
    backend.move_tcp("left", (300.0, 200.0, 40.0))  # and the driver goes on
    assert names(motion)[0] == "MoveAbsJ"
    backend.close()


@pytest.mark.slow
def test_a_calibration_grid_over_the_shipped_box_reaches_every_point(
        yumi: Any, tmp_path: Path) -> None:
    """Issue 35: ``testbed calibrate``'s 5x4 grid over the right arm's shipped box, as the
    rehearsal runs it. With the pusher down the wrist passes near its singularity over
    part of the box (axis 5 near 0, axis 4 turning fast); a way back from a point that was
    not the way out (up to clear height, then across to the gate) wound axis 4 round and
    the twin stopped the grid's 17th point with 50027 ("axis 4 0.1 deg past its limit")
    on the way back from the 16th. Back the way it came, every point is reached.

    Issue 43: each robtarget carries an arm angle the driver planned so that the line to
    it runs (drivers/yumi/line_plan.py), and the twin holds it: every point of the
    shipped box (its inner edge at ``INNER_EDGE_MM``, testbed/lab/camera_model.py) is
    reached. A point the driver could not plan would be refused before anything moves,
    named, and the grid would go on with the next."""
    from sim_twin.yumi_geometry import workspace_mm
    from testbed.lab.calibrate import GRID_INSET_MM
    from testbed.lab.camera_model import push_box
    from testbed.perception.homography import grid_points

    client, ctrl, _, motion, _ = yumi()
    box = tuple(push_box(workspace_mm(motion.cell.sides["right"])))
    backend = backend_on(client, motion, tmp_path, table_box=box,  # type: ignore[arg-type]
                         arm="right")
    points = grid_points(box, (5, 4), inset_mm=GRID_INSET_MM)  # type: ignore[arg-type]
    refused = []
    for x, y in points:
        newest = ctrl.elog.newest
        try:
            got = backend.move_tcp("right", (x, y, 10.0))
        except BackendError as exc:  # the backend's refusal (drivers/yumi/backend.py)
            assert re.match(r"arm right: the arm cannot run the program's straight lines "
                            r"holding the arm angle the controller turns along each: no "
                            r"straight line to \(\d+, -\d+, \d+\) the arm can run: .*; "
                            r"nothing was moved$", str(exc)), exc
            assert ctrl.elog.newest == newest  # nothing was started
            refused.append((round(x), round(y)))
            continue
        assert got == pytest.approx((x, y, 10.0), abs=1.0)
    assert refused == [], refused
    reached = [p for p in points if (round(p[0]), round(p[1])) not in refused]
    cmds = motion.last_run["T_ROB_R"].program.commands  # the way back: up to travel height
    assert list(cmds[0].to_point.trans) == pytest.approx([*reached[-2], 80.0], abs=0.05)
    backend.close()


def test_a_push_past_the_world_zone_is_stopped_by_the_controller(yumi: Any,
                                                                  tmp_path: Path) -> None:
    client, ctrl, cell, motion, lock = yumi()
    zone = motion.zones["left"]  # the twin's default: the workspace grown by 25 mm
    y = (zone.y0 + zone.y1) / 2
    start, past = (zone.x1 - 60.0, y, 12.0), (zone.x1 + 20.0, y, 12.0)
    gate = model_gate_joints(ArmTool("left", PUSHER_MM, ARM_ANGLE["left"]), (310.0, y, 100.0),
                             motion.arms.rest_joints("left"))  # as the driver leaves rest
    assert not isinstance(gate, str), gate
    stroke = [Waypoint("abs_j", None, 150.0, joints_deg=gate),
              Waypoint("move_l", (start[0], y, 80.0), 150.0),
              Waypoint("move_l", start, 100.0), Waypoint("move_l", past, 50.0)]
    with pytest.raises(BackendError) as info:
        client.execute({"left": stroke, "right": to(RIGHT)})
    msg = str(info.value)
    assert "\n" not in msg, msg
    assert msg.startswith("YuMi controller: event log 50000 'World zone reached': Task "
                          "T_ROB_L: the TCP of tool_pusher reached the stationary world "
                          "zone tb_wz_xhi"), msg
    got = tcps(cell, lock)
    assert got["left"][0] == pytest.approx(zone.x1, abs=0.5)  # stopped on the zone's face
    assert got["left"][2] == pytest.approx(12.0, abs=0.5)
    assert not any(e.title == "Testbed Motion Done" for e in ctrl.elog.entries())
    # A task stopped by the zone stays stopped for the driver until a person has looked:
    # the next motion is refused, naming the entry, until the program pointer is reset.
    with pytest.raises(BackendError, match=r"stopped by a RAPID error \(event log 50000 "
                                           r"'World zone reached'.*PP to Main"):
        client.execute({"left": to(LEFT)})
    ctrl.resetpp()  # the FlexPendant's "PP to Main"
    # The same through the backend: a table box wider than the zone lets a point past it
    # be asked for; the controller stops the arm where the zone begins, and says so: the
    # pusher travels above the zone's height and comes down past its face, so it stops
    # on the zone's top, over the point. (20 mm past the face: 40 mm past, the arm
    # stretched out, no line down holds an arm angle the arm can keep, and the driver
    # refuses it before anything is sent: drivers/yumi/line_plan.py.)
    # (A cell of its own, its arms at rest: from where the zone left the pusher, the twin's
    # MoveJ to the gate's point, ConfJ Off, takes an elbow whose joint path dips under the
    # floor: the measuring of the gate joints starts from rest, as testbed calibrate's.)
    client, ctrl, cell, motion, lock = yumi()
    backend = backend_on(client, motion, tmp_path, table_box=(
        zone.x0, zone.y0, zone.x1 + 80.0, zone.y1), arm="left")
    with pytest.raises(BackendError, match=r"^YuMi controller: event log 50000 'World zone "
                                           r"reached'"):
        backend.move_tcp("left", (zone.x1 + 20.0, y, 20.0))
    got = tcps(cell, lock)["left"]
    assert (got[0], got[2]) == pytest.approx((zone.x1 + 20.0, zone.zone_z), abs=0.5)
    backend.close()


# -- what the agent says of its controller at hello (run.json ``hosts``) -------------------
def test_controller_info_is_what_the_controller_says_and_never_the_login(
        tmp_path: Path) -> None:
    from drivers.yumi.rws_controller import controller_identity, controller_info
    from sim_twin.rws import serve
    from sim_twin.rws.irc5 import Identity

    ident = Identity(ctrl_id="14000-512345", rwversion="6.15.02.00", name="YUMI_LAB")
    server = serve(Irc5Controller(identity=ident), users={"lab": "s3cret-pw"})
    login = tmp_path / "rws.login"
    login.write_text("lab:s3cret-pw\n")
    login.chmod(0o600)
    try:
        info = controller_info(server.url, str(login))
        assert info == {"serial": "14000-512345", "robotware": "6.15.02.00",
                        "system": "YUMI_LAB"}
        assert controller_identity(server.url, str(login)) == "IRC5 14000-512345"
        login.write_text("lab:wrong\n")  # refused: nothing is known, nothing is guessed
        assert controller_info(server.url, str(login)) is None
    finally:
        server.stop()
    assert controller_info(server.url, None, timeout_s=0.5) is None  # unreachable
