"""The programs the YuMi's driver sends, value for value (docs/notes/tests.md, mutation
testing).

Why: ``backend.plan_push`` turns a face of a cube in the picture into a push's waypoints,
``YumiBackend._way`` prefixes the way back from where an arm stopped, and
``RwsYumiController.program`` writes each arm's RAPID (MoveAbsJ, MoveL, MoveJ) that the
controller obeys. test_yumi_backend.py checks their shape; a speed taken from the wrong
field, a zone ``z10`` for ``fine``, an axis 7 in the wrong place of a jointtarget or an
arm angle rounded otherwise does not change the shape. Here each expected value is worked
out by hand from the calibration (a homography chosen so that canonical (c0, c1) is table
(100 + 256 c1, 50 + 256 c0) mm) and from RAPID's data types (``speeddata`` [v_tcp, v_ori,
v_leax, v_reax], ``zonedata`` ``fine`` [TRUE, 0, ...] and ``z10`` [FALSE, 10, 15, 15, 1.5,
15, 1.5], a jointtarget's external axes with axis 7 first and 9E9 for the rest). Pure: no
twin, no sshd, no agent; the controller client is built against a port nobody answers and
never sends.
"""

from __future__ import annotations

import ast
import math
import re
import warnings
from typing import Any

import pytest

from drivers.errors import BackendError
from drivers.testing.fake_yumi import FakeYumiController
from drivers.yumi.arm_calibration import ArmCalibration
from drivers.yumi.arm_place import Place
from drivers.yumi.backend import LIFT_TOLERANCE_MM, ArmSetup, YumiBackend, plan_push
from drivers.yumi.credentials import FACTORY_LOGIN
from drivers.yumi.gate import GATE_HOW, calibration_gate_joints
from drivers.yumi.rws_controller import RwsYumiController
from drivers.yumi.yumi_controller import ArmPose, Waypoint

GATE_J = (10.0, -20.0, 30.0, -40.0, 50.0, -60.0, 70.0)
REST_L = (40.0, -90.0, 30.0, 0.0, 40.0, 0.0, 135.0)
REST_R = (-40.0, -90.0, 30.0, 0.0, 40.0, 0.0, -135.0)
E9 = 9e9
FINE = [True, 0, 0, 0, 0, 0, 0]
Z10 = [False, 10, 15, 15, 1.5, 15, 1.5]


def calibration(**over: Any) -> ArmCalibration:
    """Canonical (c0, c1) -> pixel (256 c0 - 0.5, 256 c1 - 0.5) on crop (0, 0, 256, 256)
    -> table (x, y) = (pixel v + 100.5, pixel u + 50.5) = (100 + 256 c1, 50 + 256 c0):
    the canonical square is the table box (100, 50, 356, 306) exactly."""
    d = {"homography": [[0, 1, 100.5], [1, 0, 50.5], [0, 0, 1]],
         "table_box_mm": [100, 50, 356, 306], "z_push_mm": 10.0, "z_travel_mm": 80.0,
         "max_speed_mm_s": 120.0, "push_speed_mm_s": 40.0, "stroke": 0.25,
         "tool_z_mm": 184.2, "rest_joints_deg": list(REST_L), "task": "T_ROB_L",
         "gate_joints_deg": list(GATE_J), **over}
    return ArmCalibration.from_dict({k: v for k, v in d.items() if v is not None}, "left")


def arm_setup(crop: tuple[int, int, int, int] = (0, 0, 256, 256), mirror: bool = False,
              **over: Any) -> ArmSetup:
    return ArmSetup("left", crop, mirror, calibration(**over))


# -- plan_push: the push's waypoints -----------------------------------------------------
def test_a_push_to_the_right_is_every_waypoint_worked_by_hand() -> None:
    # face 3 pushes along +c0; the start is half a cube (4/64) and the start offset (8/64)
    # before the centre: c0 = 0.5 - 0.1875 = 0.3125 -> y 130; the stroke 0.25 -> c0
    # 0.5625 -> y 194; c1 = 0.5 -> x 228. Speeds: max 120, push 40, down and up at 2 x 40.
    # The gate: half into the box (x 228), five eighths out from y 50 (y 210), z 100.
    assert plan_push(arm_setup(), (0.5, 0.5), 0.0, 3) == [
        Waypoint("abs_j", None, 120.0, fine=True, joints_deg=GATE_J),
        Waypoint("move_l", (228.0, 130.0, 80.0), 120.0, fine=True),
        Waypoint("move_l", (228.0, 130.0, 10.0), 80.0, fine=True),
        Waypoint("move_l", (228.0, 194.0, 10.0), 40.0, fine=True),
        Waypoint("move_l", (228.0, 194.0, 80.0), 80.0, fine=False),
        Waypoint("move_l", (228.0, 210.0, 100.0), 120.0, fine=True),
        Waypoint("abs_j", None, 120.0, fine=True, joints_deg=GATE_J),
        Waypoint("rest", None, 120.0, fine=True),
    ]


def test_the_down_and_up_speed_is_capped_by_the_maximum() -> None:
    # push 70: the stroke at 70, down and up at min(120, 140) = 120
    wps = plan_push(arm_setup(push_speed_mm_s=70.0), (0.5, 0.5), 0.0, 3)
    assert [w.speed_mm_s for w in wps] == [120.0, 120.0, 120.0, 70.0, 120.0, 120.0, 120.0,
                                           120.0]
    # push = max = 60: every speed 60
    wps = plan_push(arm_setup(push_speed_mm_s=60.0, max_speed_mm_s=60.0), (0.5, 0.5), 0.0, 3)
    assert {w.speed_mm_s for w in wps} == {60.0}


@pytest.mark.parametrize(("face", "start", "end"), [
    (0, (0.5, 0.6875), (0.5, 0.4375)),   # up: -c1
    (1, (0.6875, 0.5), (0.4375, 0.5)),   # left: -c0
    (2, (0.5, 0.3125), (0.5, 0.5625)),   # down: +c1
])
def test_each_face_comes_in_along_its_normal(face: int, start: tuple[float, float],
                                             end: tuple[float, float]) -> None:
    wps = plan_push(arm_setup(), (0.5, 0.5), 0.0, face)

    def table(c: tuple[float, float], z: float) -> tuple[float, float, float]:
        return (100 + 256 * c[1], 50 + 256 * c[0], z)

    assert [w.xyz_mm for w in wps[1:5]] == [table(start, 80.0), table(start, 10.0),
                                           table(end, 10.0), table(end, 80.0)]


def test_a_yaw_turns_the_face_normal_counter_clockwise_in_canonical_axes() -> None:
    # face 2 (down, +c1) turned by 90 deg: (c dx - s dy, s dx + c dy) = (-1, 0): along -c0
    wps = plan_push(arm_setup(), (0.5, 0.5), math.pi / 2, 2)
    # start 0.1875 behind the centre: c0 0.6875 (y 226), the stroke back to 0.4375 (y 162)
    want = [(228.0, 226.0, 80.0), (228.0, 226.0, 10.0), (228.0, 162.0, 10.0),
            (228.0, 162.0, 80.0)]
    for w, xyz in zip(wps[1:5], want, strict=True):
        assert w.xyz_mm == pytest.approx(xyz, abs=1e-9)
    # face 3 (right, +c0) turned by 90 deg: (0, 1): along +c1
    wps = plan_push(arm_setup(), (0.5, 0.5), math.pi / 2, 3)
    assert wps[2].xyz_mm == pytest.approx((180.0, 178.0, 10.0), abs=1e-9)
    assert wps[3].xyz_mm == pytest.approx((244.0, 178.0, 10.0), abs=1e-9)


@pytest.mark.parametrize(("centre", "face", "start_xy", "end_xy"), [
    # start before the box's low y edge (c0 = -0.1375): clipped to y 50; end c0 0.1125
    ((0.05, 0.5), 3, (228.0, 50.0), (228.0, 78.8)),
    # start past the high y edge (c0 = 1.1375 -> 306), end c0 0.8875 -> y 277.2
    ((0.95, 0.5), 1, (228.0, 306.0), (228.0, 277.2)),
    # along c1: start before x 100, end at c1 0.1125 -> x 128.8
    ((0.5, 0.05), 2, (100.0, 178.0), (128.8, 178.0)),
    # start past x 356; the end too (c1 1.1375 - 0.25 = 0.8875 -> x 327.2)
    ((0.5, 0.95), 0, (356.0, 178.0), (327.2, 178.0)),
])
def test_points_outside_the_box_are_clipped_to_its_edges(
        centre: tuple[float, float], face: int, start_xy: tuple[float, float],
        end_xy: tuple[float, float]) -> None:
    wps = plan_push(arm_setup(), centre, 0.0, face)
    assert wps[2].xyz_mm == pytest.approx((*start_xy, 10.0), abs=1e-9)
    assert wps[3].xyz_mm == pytest.approx((*end_xy, 10.0), abs=1e-9)


def test_the_crop_and_the_mirror_place_the_canonical_square_in_the_picture() -> None:
    # a crop 128 wide, 256 high from (10, 20): pixel centres at integers, so canonical 0
    # is at x0 - 0.5; mirrored, c0 counts from the crop's right edge
    plain = arm_setup(crop=(10, 20, 138, 276))
    assert plain.canonical_to_pixel((0.25, 0.75)) == (41.5, 211.5)
    assert plain.canonical_to_pixel((0.0, 0.0)) == (9.5, 19.5)
    mirrored = arm_setup(crop=(10, 20, 138, 276), mirror=True)
    assert mirrored.canonical_to_pixel((0.25, 0.75)) == (105.5, 211.5)
    # the table through the homography: x = v + 100.5, y = u + 50.5
    assert mirrored.canonical_to_table((0.25, 0.75)) == (312.0, 156.0)


def test_a_push_point_off_the_homography_names_the_point() -> None:
    # w = 1 - (u + 0.5) / 128 vanishes at canonical c0 = 0.5 (u = 127.5), and there
    # x = 100 w + v - 127.5 vanishes too at c1 = 0.5 (v = 127.5): x / w is 0 / 0, y / w
    # is 178 / 0. Face 1 starts at c0 = 0.3125 + 0.1875 = 0.5 from a centre at 0.3125.
    # numpy's warnings of both divisions are silenced: the error is the one line below.
    setup = arm_setup(homography=[[-100 / 128, 1, 100 - 50 / 128 - 127.5], [1, 0, 50.5],
                                  [-1 / 128, 0, 1 - 0.5 / 128]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(BackendError) as err:
            plan_push(setup, (0.3125, 0.5), 0.0, 1)
    assert str(err.value) == ("arm left: push point (0.5, 0.5) maps to a non-finite table "
                              "point; check the calibration's homography")


def test_a_push_without_gate_joints_is_refused_with_the_fix() -> None:
    with pytest.raises(BackendError) as err:
        plan_push(arm_setup(gate_joints_deg=None), (0.5, 0.5), 0.0, 3)
    assert str(err.value) == (f"arm left: its calibration has no 'gate_joints_deg' (the "
                              f"gate's joints): nothing is sent; {GATE_HOW}")


# -- YumiBackend._way: the way from where the arm is ------------------------------------
def backend(**over: Any) -> YumiBackend:
    ctrl = FakeYumiController({"left": (100.0, 400.0, 300.0)}, rest_joints={"left": REST_L})
    return YumiBackend([arm_setup(**over)], object(), ctrl)  # type: ignore[arg-type]


PUSH = [Waypoint("abs_j", None, 120.0, joints_deg=GATE_J),
        Waypoint("move_l", (228.0, 130.0, 80.0), 120.0)]
TO_REST = [Waypoint("rest", None, 120.0)]


def test_from_rest_a_program_runs_as_written_and_the_way_to_rest_is_nothing() -> None:
    b = backend()
    here = Place("rest", (100.0, 400.0, 300.0))
    assert b._way("left", here, PUSH) == PUSH
    assert b._way("left", here, TO_REST) == []
    assert b._way("left", here, []) == []


def test_from_the_gate_a_program_runs_as_written_and_to_rest_is_the_rest_move_alone() -> None:
    b = backend()
    here = Place("gate", (228.0, 210.0, 100.0))
    assert b._way("left", here, PUSH) == PUSH
    assert b._way("left", here, TO_REST) == TO_REST
    assert b._way("left", here, [*TO_REST, Waypoint("rest", None, 5.0)]) == TO_REST


def test_from_a_leg_the_way_back_is_up_to_the_gate_point_then_its_joints() -> None:
    back = [Waypoint("move_l", (250.0, 150.0, 80.0), 80.0),  # up at min(120, 2 x 40)
            Waypoint("move_l", (228.0, 210.0, 100.0), 120.0),
            Waypoint("abs_j", None, 120.0, joints_deg=GATE_J)]
    b = backend()
    low = Place("leg", (250.0, 150.0, 10.0))
    assert b._way("left", low, TO_REST) == [*back, *TO_REST]
    assert b._way("left", low, PUSH) == [*back, PUSH[1]]  # the program's MoveAbsJ: done
    # up at 120 when twice the push speed (140) is above the maximum
    fast = backend(push_speed_mm_s=70.0)._way("left", low, TO_REST)
    assert fast[0] == Waypoint("move_l", (250.0, 150.0, 80.0), 120.0)
    # within LIFT_TOLERANCE_MM (1) of travel height: no lift; just beyond it: the lift
    assert LIFT_TOLERANCE_MM == 1.0
    assert b._way("left", Place("leg", (250.0, 150.0, 79.0)), TO_REST) == [*back[1:],
                                                                          *TO_REST]
    assert b._way("left", Place("leg", (250.0, 150.0, 78.9)), TO_REST)[0] == Waypoint(
        "move_l", (250.0, 150.0, 80.0), 80.0)


# -- RwsYumiController.program: the RAPID each task gets -------------------------------
def client(**poses: ArmPose) -> RwsYumiController:
    return RwsYumiController("http://127.0.0.1:1", poses or {
        "left": ArmPose("T_ROB_L", "ROB_L", REST_L, tool_z_mm=184.2)}, login=FACTORY_LOGIN)


def commands(rapid: str) -> list[tuple[str, list[Any]]]:
    """Each motion instruction of ``rapid`` with its arguments read as data (TRUE/FALSE
    as booleans), the tool and work object it names dropped."""
    out = []
    for line in rapid.splitlines():
        m = re.fullmatch(r"\s*(MoveAbsJ|MoveL|MoveJ|WaitTime) (.*);", line)
        if m:
            args = m.group(2).replace(r", motion_program_tool\Wobj:=motion_program_wobj", "")
            args = args.replace("TRUE", "True").replace("FALSE", "False")
            out.append((m.group(1), ast.literal_eval(f"[{args}]")))
    return out


def tool_of(rapid: str) -> list[Any]:
    m = re.search(r"TASK PERS tooldata motion_program_tool := (.*);", rapid)
    assert m is not None, rapid
    return ast.literal_eval(m.group(1).replace("TRUE", "True").replace("FALSE", "False"))


def gate_of(angle: float) -> tuple[float, ...]:
    """The model's gate joints of the left arm at arm angle ``angle`` over the shipped
    left box (the joints the lines then start from)."""
    cal = {"table_box_mm": [150.0, 50.0, 470.0, 370.0], "z_clear_mm": 100.0,
           "tool_z_mm": 184.2, "arm_angle_deg": angle, "rest_joints_deg": list(REST_L),
           "task": "T_ROB_L"}
    return tuple(calibration_gate_joints("left", cal))


def test_a_program_is_moveabsj_and_movel_with_rapids_own_data() -> None:
    gate = gate_of(-40.0)
    wps = [Waypoint("abs_j", None, 100.0, joints_deg=gate),
           Waypoint("move_l", (400.0, 250.0, 80.0), 60.0),
           Waypoint("move_l", (400.0, 250.0, 10.0), 20.0, fine=False),
           Waypoint("rest", None, 90.0)]
    rapid = client().program("left", wps).get_program_rapid()
    assert commands(rapid) == [
        ("MoveAbsJ", [[list(gate[:6]), [gate[6], E9, E9, E9, E9, E9]],
                      [100.0, 100.0, 1000.0, 100.0], FINE]),
        # the arm angle the left arm's lines hold by default: -40 (drivers/yumi/reach.py)
        ("MoveL", [[[400.0, 250.0, 80.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 4.0],
                    [-40.0, E9, E9, E9, E9, E9]], [60.0, 100.0, 1000.0, 100.0], FINE]),
        ("MoveL", [[[400.0, 250.0, 10.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 4.0],
                    [-40.0, E9, E9, E9, E9, E9]], [20.0, 100.0, 1000.0, 100.0], Z10]),
        ("MoveAbsJ", [[[40.0, -90.0, 30.0, 0.0, 40.0, 0.0], [135.0, E9, E9, E9, E9, E9]],
                      [90.0, 100.0, 1000.0, 100.0], FINE]),
    ]
    # the tool: the calibration's frame, no rotation, and tool_pusher's shipped load
    assert tool_of(rapid) == [True, [[0, 0, 184.2], [1, 0, 0, 0]],
                              [0.272, [7.5, 11.5, 53.8], [1, 0, 0, 0], 0.0003, 0.00032, 9e-05]]


def test_a_robtarget_carries_the_calibrations_arm_angle_to_four_decimals() -> None:
    angle = -37.123456
    gate = gate_of(angle)
    pose = ArmPose("T_ROB_L", "ROB_L", REST_L, tool_z_mm=200.5, arm_angle_deg=angle,
                   tool_quat_wxyz=(0.0, 0.0, 1.0, 0.0), robconf=(1.0, -1.0, 0.0, 4.0))
    wps = [Waypoint("abs_j", None, 50.0, joints_deg=gate),
           Waypoint("move_l", (400.0, 250.0, 80.0), 50.0),
           Waypoint("move_j", (350.0, 200.0, 80.0), 40.0)]
    got = commands(client(left=pose).program("left", wps).get_program_rapid())
    assert got[1] == ("MoveL", [[[400.0, 250.0, 80.0], [0.0, 0.0, 1.0, 0.0],
                                 [1.0, -1.0, 0.0, 4.0], [-37.1235, E9, E9, E9, E9, E9]],
                                [50.0, 100.0, 1000.0, 100.0], FINE])
    assert got[2][0] == "MoveJ" and got[2][1][0][0] == [350.0, 200.0, 80.0]
    assert got[2][1][0][3][0] == pytest.approx(angle, abs=0.01)
    assert got[2][1][1] == [40.0, 100.0, 1000.0, 100.0]


def test_a_program_that_starts_with_a_line_plans_from_the_given_joints() -> None:
    gate = gate_of(-40.0)
    line = [Waypoint("move_l", (400.0, 250.0, 80.0), 60.0)]
    ctrl = client()
    # given: the controller is not asked (it would not answer: port 1)
    got = commands(ctrl.program("left", line, start_joints=gate).get_program_rapid())
    assert got == [("MoveL", [[[400.0, 250.0, 80.0], [0.0, 0.0, 1.0, 0.0],
                               [0.0, 0.0, 0.0, 4.0], [-40.0, E9, E9, E9, E9, E9]],
                              [60.0, 100.0, 1000.0, 100.0], FINE])]
    asked: list[str] = []

    def joints() -> dict[str, tuple[float, ...]]:
        asked.append("joints")
        return {"left": gate, "right": REST_R}

    ctrl.joints = joints  # type: ignore[method-assign]
    assert commands(ctrl.program("left", line).get_program_rapid()) == got
    assert asked == ["joints"]
    # a program that starts with a joint target is planned from it: nothing is asked
    ctrl.program("left", [Waypoint("rest", None, 60.0), *line])
    ctrl.program("left", [Waypoint("abs_j", None, 60.0, joints_deg=gate), *line])
    assert asked == ["joints"]
    # a MoveJ first is planned from where the arm is, as a line is
    got = commands(ctrl.program("left", [Waypoint("move_j", (400.0, 250.0, 80.0), 60.0)]
                                ).get_program_rapid())
    assert asked == ["joints", "joints"] and [c for c, _ in got] == ["MoveJ"]


def test_a_line_is_planned_from_where_the_arm_is_not_from_nowhere() -> None:
    """Axis 1 at 165 deg (its limit 168.5, the plan keeps 3 deg of room): no line from
    there runs, so the program is refused, though from the gate joints it runs."""
    line = [Waypoint("move_l", (400.0, 250.0, 80.0), 60.0)]
    gate = gate_of(-40.0)
    client().program("left", line, start_joints=gate)
    with pytest.raises(BackendError) as err:
        client().program("left", line, start_joints=(165.0, *gate[1:]))
    assert str(err.value).startswith("arm left: the driver cannot plan its program: no "
                                     "straight line to (400, 250, 80) the arm can run: ")
    assert str(err.value).endswith("; nothing is sent")


def test_a_target_out_of_reach_is_refused_with_nothing_built() -> None:
    with pytest.raises(BackendError) as err:
        client().program("left", [Waypoint("move_l", (2000.0, 0.0, 80.0), 50.0)],
                         start_joints=gate_of(-40.0))
    assert str(err.value) == ("arm left: the driver cannot plan its program: (2000, 0, 80): "
                              "out of reach by 1350 mm; nothing is sent")


def test_an_arm_whose_side_cannot_be_told_is_refused() -> None:
    ctrl = client(middle=ArmPose("T_ROB_X", "ROB_X", REST_L, tool_z_mm=184.2))
    with pytest.raises(BackendError) as err:
        ctrl.program("middle", [Waypoint("rest", None, 50.0)])
    assert str(err.value) == ("arm middle: task T_ROB_X is not an IRB 14000 arm's; the "
                              "driver cannot tell its robtargets' arm angle; nothing is sent")


def test_an_arm_on_another_task_is_told_by_its_name_and_an_empty_program_is_empty() -> None:
    # the task says nothing of the side: the arm's name "left" does, so it is planned
    ctrl = client(left=ArmPose("T_ONE", "ROB_1", REST_L, tool_z_mm=184.2))
    got = commands(ctrl.program("left", [Waypoint("rest", None, 50.0)]).get_program_rapid())
    assert got == [("MoveAbsJ", [[[40.0, -90.0, 30.0, 0.0, 40.0, 0.0],
                                  [135.0, E9, E9, E9, E9, E9]],
                                 [50.0, 100.0, 1000.0, 100.0], FINE])]
    assert commands(client().program("left", []).get_program_rapid()) == []


def test_a_pose_without_the_pushers_length_sends_nothing() -> None:
    ctrl = client(left=ArmPose("T_ROB_L", "ROB_L", REST_L))
    with pytest.raises(BackendError) as err:
        ctrl.program("left", [Waypoint("rest", None, 50.0)])
    assert str(err.value) == ("arm left: no tool_z_mm (the pusher's length) to send; the "
                              "calibration file must give it (robot/README.md, 'The tool "
                              "frame')")
    with pytest.raises(BackendError) as err:
        ctrl.stay("T_ROB_L")  # its stay program carries its tool too
    assert str(err.value).startswith("arm left: no tool_z_mm (the pusher's length)")


def test_the_right_arm_holds_plus_forty_by_default() -> None:
    pose = ArmPose("T_ROB_R", "ROB_R", REST_R, tool_z_mm=184.2)
    cal = {"table_box_mm": [150.0, -370.0, 470.0, -50.0], "z_clear_mm": 100.0,
           "tool_z_mm": 184.2, "rest_joints_deg": list(REST_R), "task": "T_ROB_R"}
    gate = tuple(calibration_gate_joints("right", cal))
    got = commands(client(right=pose).program(
        "right", [Waypoint("abs_j", None, 50.0, joints_deg=gate),
                  Waypoint("move_l", (400.0, -250.0, 80.0), 50.0)]).get_program_rapid())
    assert got[1][1][0][3] == [40.0, E9, E9, E9, E9, E9]


# -- stay and tasks: what the other task runs --------------------------------------------
class ToolRws:
    """The one RWS read a stay program of a task without an arm makes: tool_pusher."""

    def __init__(self, text: str | None) -> None:
        self.text, self.reads = text, []  # type: ignore[var-annotated]

    def get_rapid_variable(self, var: str, task: str) -> str:
        self.reads.append((var, task))
        if self.text is None:
            raise RuntimeError("NO_SUCH_SYMBOL")
        return self.text


def test_a_stay_is_one_waittime_with_the_arms_tool_or_the_controllers() -> None:
    ctrl = client()
    own = ctrl.stay("T_ROB_L").get_program_rapid()
    assert commands(own) == [("WaitTime", [0])]
    assert tool_of(own)[1] == [[0, 0, 184.2], [1, 0, 0, 0]]
    rws = ToolRws("[TRUE,[[0,0,175.5],[1,0,0,0]],[0.3,[0,0,50],[1,0,0,0],0,0,0]]")
    ctrl._rws = rws
    other = ctrl.stay("T_ROB_R").get_program_rapid()
    assert commands(other) == [("WaitTime", [0])]
    assert tool_of(other)[1] == [[0, 0, 175.5], [1, 0, 0, 0]]
    assert rws.reads == [("TestbedTask_R/tool_pusher", "T_ROB_R")]
    ctrl.stay("T_ROB_R")
    assert len(rws.reads) == 1  # read once per client


def test_a_stay_for_a_task_without_our_rapid_is_refused() -> None:
    ctrl = client()
    ctrl._rws = ToolRws(None)
    with pytest.raises(BackendError) as err:
        ctrl.stay("T_ROB_R")
    assert str(err.value) == ("YuMi controller: cannot read tool_pusher of task T_ROB_R for "
                              "its stay program; is the testbed RAPID loaded? "
                              "(robot/README.md)")


def test_every_start_runs_both_motion_tasks_the_arms_first() -> None:
    assert client().tasks() == ["T_ROB_L", "T_ROB_R"]
    assert client(right=ArmPose("T_ROB_R", "ROB_R", REST_R, tool_z_mm=1.0)).tasks() == [
        "T_ROB_R", "T_ROB_L"]
    both = client(a=ArmPose("T_ROB_R", "ROB_R", REST_R, tool_z_mm=1.0),
                  b=ArmPose("T_ROB_L", "ROB_L", REST_L, tool_z_mm=1.0))
    assert both.tasks() == ["T_ROB_R", "T_ROB_L"]
    # a task that is not an IRB 14000's: only the arms' own
    assert client(x=ArmPose("T_ONE", "ROB_1", REST_L, tool_z_mm=1.0)).tasks() == ["T_ONE"]
