"""The IRB 14000's arms on the operator's side: kinematics, refusals, the layout's checks.

``drivers/yumi/irb14000.py`` (the chains), ``irb14000_ik.py`` (targets with the pusher
down), ``arm_shapes.py`` (clearances) and ``layout_check.py`` (what ``testbed check``
and ``testbed calibrate`` fail on, through ``check_report.controller_report``, the
function ``testbed check`` calls for a YuMi host). The shipped layout
(``sim_twin/yumi_geometry.py``, ``testbed/lab/camera_model.py``) must pass with margin;
the rest pose shipped before issue 29 must not.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from driver_fakes import write_video

from drivers.cameras.camera import VideoCaptureCamera
from drivers.errors import BackendError
from drivers.testing.fake_yumi import FakeYumiController
from drivers.yumi.arm_calibration import ArmCalibration
from drivers.yumi.arm_shapes import arm_capsules, min_distance
from drivers.yumi.backend import ArmSetup, YumiBackend
from drivers.yumi.check_report import controller_report
from drivers.yumi.controller_state import RAPID_VERSION
from drivers.yumi.gate import calibration_gate_joints
from drivers.yumi.irb14000 import JOINT_ORIGINS, abb_to_chain, arm, chain_to_abb
from drivers.yumi.irb14000_ik import solve_pose
from drivers.yumi.layout_check import check_layout, layout_of
from drivers.yumi.reach import ARM_ANGLE_DEG, REACH_MARGIN_MM, ArmTool, corner_reaches
from sim_twin.yumi_geometry import REST_JOINTS_DEG, CameraModel, workspace_mm
from testbed.lab.camera_model import PUSH_ARM_ANGLE_DEG, true_calibration
from testbed.lab.camera_model import REST_JOINTS_DEG as LAB_REST_JOINTS

OLD_REST = {"left": [0.0, -130.0, 30.0, 0.0, 40.0, 0.0, -135.0],
            "right": [0.0, -130.0, 30.0, 0.0, 40.0, 0.0, 135.0]}
"""The rest joints shipped before issue 29 (testbed/lab/camera_model.py)."""


def test_forward_kinematics_keeps_the_links_rigid_and_the_arms_mirrored() -> None:
    rng = np.random.default_rng(1)
    left, right = arm("left"), arm("right")
    for _ in range(50):
        q = rng.uniform(left.lower, left.upper)
        p = left.pose(q)
        for k, (xyz, _) in enumerate(JOINT_ORIGINS):  # each link as long as described
            assert np.linalg.norm(p.frames[k + 1][:3, 3] - p.frames[k][:3, 3]) == \
                pytest.approx(math.hypot(*xyz), abs=1e-9)
        mirrored = q * np.array([-1, 1, -1, 1, -1, 1, -1])
        r = right.pose(mirrored).flange[:3, 3]  # the description's two shoulders mirror
        # each other to its rounding (0.003 rad): a few mm at the arm's length
        assert r == pytest.approx(p.flange[:3, 3] * np.array([1, -1, 1]), abs=5.0)
    assert chain_to_abb(abb_to_chain([1, 2, 3, 4, 5, 6, 7])) == [1, 2, 3, 4, 5, 6, 7]


def test_known_poses() -> None:
    """All joints at zero stretch the left arm forward across the body at shoulder
    height; the old rest joints (axis 7 -135 on the left) put its flange on the RIGHT side
    of the body, high up: the arms cross there."""
    zero = arm("left").pose([0.0] * 7).flange[:3, 3]
    assert zero == pytest.approx([568.6, -5.0, 413.6], abs=0.5)
    crossed = arm("left").pose_abb(OLD_REST["left"]).flange[:3, 3]
    assert crossed[1] < -100 and crossed[2] > 450


def test_ik_round_trips_random_joints_within_limits() -> None:
    rng = np.random.default_rng(7)
    for side in ("left", "right"):
        model = arm(side)
        solved = 0
        for _ in range(40):
            q = rng.uniform(model.lower + 5, model.upper - 5)
            target = model.pose(q).flange
            near = q + rng.uniform(-8, 8, 7)
            near[2] = q[2]
            sol = solve_pose(model, target, q[2], current=near)
            if sol.kind == "singular":
                continue
            assert sol.pose is not None, sol.reason
            assert sol.pose.chain_deg[2] == pytest.approx(q[2])  # the arm angle is kept
            assert sol.pose.flange[:3, 3] == pytest.approx(target[:3, 3], abs=0.1)
            assert sol.pose.flange[:3, :3] == pytest.approx(target[:3, :3], abs=1e-3)
            assert model.limit_excess(sol.pose.chain_deg) is None
            solved += 1
        assert solved >= 30


ROBOTSTUDIO = (  # chain joints (deg: axes 1, 2, 7, 3, 4, 5, 6); RobotStudio's arm angle with
    # the reference direction along axis 1 and along y, the single-arm YuMi in its own
    # frame (Elias and Wen, arXiv 2505.23111: rpiRobotics/yumi-ik,
    # unit_tests/compare_to_robotstudio.m; the twin's test has the same figures)
    ((0,) * 7, 0.0, 90.0), ((20,) * 7, 6.86, 105.54), ((30,) * 7, 14.50, 99.26),
    ((-40,) * 7, 106.67, 15.68), ((-80,) * 7, 99.01, -26.0),
    ((104, -31, 1, -18, -55, 117, 69), 19.58, -165.56),
    ((162, 1, -23, -88, 241, 98, -44), 80.07, -131.03),
    ((-20, -139, -144, 77, -263, 128, -104), 139.68, -15.92),
    ((67, -142, 121, 78, -38, 113, -194), -146.69, 119.74),
    ((-58, -138, -35, 70, -283, 133, 207), 165.86, 50.38),
)


def _turn(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def test_the_drivers_arm_angle_is_robotstudios_and_the_twins() -> None:
    """A robtarget's eax_a is ABB's arm angle (drivers/yumi/arm_angle.py), written apart
    from the twin's (sim_twin/sew_angle.py): RobotStudio's 20 published figures within
    0.3 deg at 18 and 3.3 at the two extreme poses (as the twin's), and the two models
    within 0.1 deg over random joints within the limits, both arms; with the reference
    up (the assumed ARM_ANGLE_REFERENCE of both) and along the base's x."""
    from drivers.yumi.arm_angle import ARM_ANGLE_REFERENCE, arm_angle_deg
    from sim_twin.sew_angle import ARM_ANGLE_REFERENCE as TWIN_REFERENCE
    from sim_twin.sew_angle import arm_angle as twin_arm_angle
    from sim_twin.yumi_arms import ArmModel

    assert ARM_ANGLE_REFERENCE == TWIN_REFERENCE == (0.0, 0.0, 1.0)
    m = arm("left")
    up, their_y = (0.0, 0.0, 1.0), (0.0, -1.0, 0.0)  # in the arm's own frame
    errors = sorted(_turn(arm_angle_deg(m.pose(q), ref), want)
                    for q, along_z, along_y in ROBOTSTUDIO
                    for ref, want in ((up, along_z), (their_y, along_y)))
    assert errors[17] < 0.3 and errors[-1] < 3.3, errors
    rng = np.random.default_rng(11)
    worst = 0.0
    for side in ("left", "right"):
        ours, theirs = arm(side), ArmModel(side)
        for _ in range(200):
            q = rng.uniform(ours.lower, ours.upper)
            for ref in ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0)):
                worst = max(worst, _turn(arm_angle_deg(ours.pose(q), ref),
                                         twin_arm_angle(theirs.pose(q), ref)))
    assert worst < 0.1, worst


def test_the_arm_angle_is_not_axis_7_and_its_gradient_is_its_slope() -> None:
    """Two joint vectors with the same axis 7 and different arm angles (the elbow's plane
    turns with axes 1 and 2), and the numerical gradient the line solver uses against
    the arm angle's change over a small joint step."""
    from drivers.yumi.arm_angle import arm_angle_deg, arm_angle_gradient

    m = arm("left")
    a = arm_angle_deg(m.pose([-58.0, 11.0, 130.0, 45.0, 65.0, -24.0, 141.0]))
    b = arm_angle_deg(m.pose([-88.0, -56.0, 130.0, 76.0, 167.0, 93.0, 60.0]))
    assert _turn(a, b) > 50.0 and _turn(a, 130.0) > 90.0  # 57 and 121 deg
    rng = np.random.default_rng(5)
    for _ in range(20):
        q = rng.uniform(m.lower + 10, m.upper - 10)
        psi, grad = arm_angle_gradient(m.pose(q))
        dq = rng.uniform(-0.05, 0.05, 7)
        moved = math.radians(arm_angle_deg(m.pose(q + dq)))
        assert (moved - psi + math.pi) % (2 * math.pi) - math.pi == pytest.approx(
            float(grad @ np.radians(dq)), abs=2e-5)


def test_a_planned_line_holds_the_tip_on_the_line_and_the_arm_angle_turning_evenly() -> None:
    """The sweep's straight move (drivers/yumi/line_plan.py, what the controller runs):
    from the shipped gate to over the box's far outer corner, every sample's tip on the
    line within 0.1 mm and its arm angle the evenly turned one within 0.01 deg, the
    wrist's axes turned evenly, the end the planned joints (their arm angle the one
    sent)."""
    from drivers.yumi.arm_angle import angle_step, arm_angle_deg
    from drivers.yumi.line_plan import planned_targets
    from drivers.yumi.wrist_line import WRIST
    from drivers.yumi.yumi_controller import Waypoint

    cal = shipped("left")
    tool = ArmTool("left", 184.2, cal["arm_angle_deg"])
    m = tool.model
    gate = m.pose_abb(cal["gate_joints_deg"]).chain_deg
    far = (470.0, 370.0, 80.0)
    plan, why = planned_targets(tool, None, None, [
        Waypoint("abs_j", None, 100.0, joints_deg=tuple(cal["gate_joints_deg"])),
        Waypoint("move_l", far, 100.0)])
    assert why is None
    line = plan[1].line
    assert len(line) > 10 and line[-1] == plan[1].chain_deg
    psi0, psi1 = arm_angle_deg(m.pose(gate)), plan[1].arm_angle_deg
    assert psi1 is not None and psi1 == pytest.approx(arm_angle_deg(m.pose(line[-1])),
                                                      abs=0.01)
    start = m.pose(gate).tcp(184.2)
    wrist0, wrist1 = np.asarray(gate)[list(WRIST)], np.asarray(line[-1])[list(WRIST)]
    for k, q in enumerate(line, 1):
        f = k / len(line)
        tip = m.pose(q).tcp(184.2)
        assert tip == pytest.approx(start + (np.asarray(far) - start) * f, abs=0.1)
        assert _turn(arm_angle_deg(m.pose(q)), psi0 + angle_step(psi0, psi1) * f) < 0.01
        assert np.asarray(q)[list(WRIST)] == pytest.approx(
            wrist0 + (wrist1 - wrist0) * f, abs=1e-6)
    assert max(abs(q[2] - gate[2]) for q in line) > 20.0  # axis 7 turns as it must


def test_an_unreachable_target_and_a_joint_limit_are_refused_with_the_number() -> None:
    far = ArmTool("left", 100.0, -40.0).solve((900.0, 300.0, 10.0))
    assert far.pose is None and far.kind == "reach"
    n = float(re.fullmatch(r"out of reach by (\d+) mm", far.reason).group(1))  # type: ignore[union-attr]
    assert 200 < n < 400
    tight = ArmTool("left", 100.0, 60.0).solve((160.0, 50.0, 10.0))  # reached at -40
    assert tight.pose is None and tight.kind == "limit"
    assert tight.reason == "no joints within the limits at arm angle 60 deg"
    assert ArmTool("left", 100.0, -40.0).solve((160.0, 50.0, 10.0)).pose is not None


def shipped(side: str, **over: Any) -> dict[str, Any]:
    """A side's calibration as the twin's true one, with the 184.2 mm pusher; its gate
    joints those of the gate after ``over`` (as ``testbed calibrate`` would measure)."""
    cam = {**CameraModel.default().as_json(),
           "workspaces_mm": {s: list(workspace_mm(s)) for s in ("left", "right")}}
    cal = {**true_calibration(cam, side), "tool_z_mm": 184.2, **over}
    if "gate_joints_deg" not in over:
        cal["gate_joints_deg"] = calibration_gate_joints(side, cal)
    return cal


def check(cals: dict[str, dict[str, Any]], zone_z: float = 80.0) -> tuple[list[str], list[str]]:
    """``testbed check``'s YuMi report of a ready controller and these calibrations."""
    tasks = {a: c["task"] for a, c in cals.items()}
    rep = {"options": ["616-1", "623-1", "604-2", "608-1"],
           "state": {"opmode": "AUTO", "ctrlstate": "motoron", "execstate": "stopped"},
           "tasks": {t: {"active": True, "excstate": "ready"} for t in tasks.values()},
           "rapid": {t: {"version": RAPID_VERSION,
                         "zones": {"tb_zone_lo": [125, -395, 0], "tb_zone_hi": [495, 395, 0],
                                   "tb_zone_z": zone_z, "tb_floor_z": 0}}
                     for t in tasks.values()}}
    info = {"controller": rep, "camera": {"size": [640, 480]},
            "layout": {a: {**c} for a, c in cals.items()}}
    return controller_report("yumi-a", info)


@pytest.mark.slow
def test_every_corner_of_the_shipped_workspaces_is_reachable_with_margin() -> None:
    """Every corner is reachable with margin at the arm angle the calibration holds, and
    the driver's path to every corner and back runs holding it (issue 43: before, axis 7
    was held and the two inner near corners (150, +-75) were a FAULT: no line from the
    gate reached them). The lab's copies of the rest and of the arm angle are the
    driver's."""
    lines, faults = check({s: shipped(s) for s in ("left", "right")})
    assert faults == []
    for side in ("left", "right"):
        cal = shipped(side)
        assert cal["arm_angle_deg"] == ARM_ANGLE_DEG[side]
        tool = ArmTool(side, 184.2, cal["arm_angle_deg"])
        for c in corner_reaches(tool, workspace_mm(side), (10.0, 80.0, 100.0)):
            assert c.margin_mm is not None and c.margin_mm >= REACH_MARGIN_MM, c
    assert any("reach margin" in line for line in lines)
    gap = next(x for x in lines if "swept volumes" in x)
    assert int(re.search(r"(-?\d+) mm apart", gap).group(1)) >= 25, gap  # type: ignore[union-attr]
    assert LAB_REST_JOINTS == REST_JOINTS_DEG  # the lab's copy of the twin's rest
    assert PUSH_ARM_ANGLE_DEG == ARM_ANGLE_DEG["left"] == -ARM_ANGLE_DEG["right"]


@pytest.mark.slow
def test_the_old_rest_pose_with_a_100mm_pusher_is_a_fault() -> None:
    cals = {s: shipped(s, rest_joints_deg=OLD_REST[s]) for s in ("left", "right")}
    _, faults = check(cals)
    assert any(re.match(r"arms left and right: at rest their \w[\w ()0-9]* and .* are -\d+ "
                        r"mm apart", f) for f in faults), faults


def test_a_rest_pose_below_the_zone_ceiling_or_in_view_is_a_fault() -> None:
    low = ArmTool("left", 184.2, -40.0).solve((300.0, 210.0, 50.0))
    assert low.pose is not None
    cals = {"left": shipped("left", rest_joints_deg=low.pose.abb_deg)}
    _, faults = check(cals)
    assert any("puts the pusher's tip at z 50 mm, below the world zone's tb_zone_z 80"
               in f for f in faults), faults
    assert any("is in the camera's view" in f for f in faults), faults


@pytest.mark.slow
def test_arms_whose_sweeps_meet_are_a_fault() -> None:
    """Two table boxes side by side with no gap: the grippers over the inner edges meet."""
    cals = {"left": shipped("left", table_box_mm=[150, 0, 470, 320]),
            "right": shipped("right", table_box_mm=[150, -320, 470, 0])}
    lays = [layout_of(a, c) for a, c in cals.items()]
    _, faults = check_layout([lay for lay in lays if lay is not None])
    assert any(re.match(r"arms left and right: on their way .* come -?\d+ mm close", f)
               for f in faults), faults
    rest = {s: arm(s).pose_abb(REST_JOINTS_DEG[s]) for s in ("left", "right")}
    gap, _, _ = min_distance(arm_capsules(rest["left"], 100.0),
                             arm_capsules(rest["right"], 100.0))
    assert gap >= 25.0


def test_the_driver_refuses_an_unreachable_target_before_anything_moves(tmp_path: Path) -> None:
    video = write_video(tmp_path / "cam.avi", [np.zeros((48, 64, 3), np.uint8)])
    cal = shipped("left", homography=np.eye(3).tolist(), table_box_mm=[0, 0, 1000, 1000],
                  gate_xy_mm=[310.0, 250.0])  # the shipped gate (the box's is out of reach)
    (tmp_path / "left.json").write_text(json.dumps(cal))
    setup = ArmSetup("left", (0, 0, 32, 32), False,
                     ArmCalibration.load(tmp_path / "left.json", "left"))
    ctrl = FakeYumiController({"left": (185.0, 674.0, 448.0)},
                              rest_joints={"left": tuple(cal["rest_joints_deg"])})
    backend = YumiBackend([setup], VideoCaptureCamera(str(video)), ctrl)
    try:
        with pytest.raises(BackendError, match=r"arm left: target \(900, 300, 80\) mm cannot "
                                               r"be reached .*out of reach by \d+ mm; nothing "
                                               r"was moved"):
            backend.move_tcp("left", (900.0, 300.0, 10.0))
        assert ctrl.programs == []
        backend.move_tcp("left", (300.0, 200.0, 10.0))  # a reachable one still moves
        assert len(ctrl.programs) == 1
    finally:
        backend.close()


@pytest.mark.slow
def test_boxes_to_the_workspaces_inner_edge_are_a_fault_where_the_forearms_meet() -> None:
    """Boxes to the workspaces' inner edge (|y| = 50; the shipped ones stop at 75,
    testbed/lab/camera_model.py INNER_EDGE_MM): on the driver's paths the two forearms
    meet over the inner far corners, and the layout check FAULTs it, naming both arms;
    the shipped boxes keep them 25 mm or more apart (the test above)."""
    whole = {s: shipped(s, table_box_mm=list(workspace_mm(s))) for s in ("left", "right")}
    _, faults = check(whole)
    assert any(re.match(r"arms left and right: on their way between rest and their table "
                        r"boxes their forearm and forearm come -?\d+ mm close \(want 25 mm\)",
                        f) for f in faults), faults
    assert all(abs(shipped(s)["table_box_mm"][1 if s == "left" else 3]) == 75.0
               for s in ("left", "right"))
