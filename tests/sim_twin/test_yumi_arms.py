"""The hardware twin's arms: the IRB 14000's kinematics, ABB's arm angle, and its controller
refusing what the robot refuses, with the controller's codes.

Through the UNCHANGED ABB client against a real ``TestbedRapid`` twin (our RAPID's start
hook on a real ``YumiTwinCell``): a target out of reach (50050), a target reachable only
past a joint limit (50027), two arms driven into each other (50204, stopped where the
links touch, every task), an arm driven into the table (50204), and a MoveJ whose
configuration the arm cannot keep (50080, ConfJ on: the library's RAPID). The model
itself: forward and inverse kinematics agree, the link lengths are the published ones,
and the operator's model (``drivers/yumi/irb14000.py``, written separately from the same
numbers) puts every link where the twin's does. The arm angle (a robtarget's ``eax_a``)
is ABB's shoulder-elbow-wrist angle, checked against RobotStudio's published figures, and
the controller holds it exactly along a line, axis 7 moving as it must, or refuses.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
import twin_rws
from abb_motion_program_exec import abb_motion_program_exec_client as mpe
from arm_plan import plan
from arm_plan import program as planned_program

from sim_twin.rws import Irc5Controller, RwsServer
from sim_twin.rws.arm_supervision import CONTACT_MM, flange_at
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.motion_exec import CellMotion
from sim_twin.rws.rws_service import RwsService
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
from sim_twin.sew_angle import ARM_ANGLE_REFERENCE, arm_angle
from sim_twin.yumi_arms import _LINKS, DEFAULT_TOOL_MM, ArmModel, abb_to_chain, clearance
from sim_twin.yumi_cell import YumiTwinCell
from sim_twin.yumi_ik import _pick, configuration, ranked, solve

Made = tuple[Any, Irc5Controller, YumiTwinCell, Any]


@pytest.fixture
def twin() -> Iterator[Callable[..., Made]]:
    made: list[tuple[RwsServer, YumiTwinCell]] = []

    def make(hook: type[CellMotion] = TestbedRapid, tool_mm: float = DEFAULT_TOOL_MM) -> Made:
        cell = YumiTwinCell(3)
        motion = hook(cell, threading.Lock(), YUMI_UNITS, pusher_length_mm=tool_mm)
        ctrl = Irc5Controller(units=YUMI_UNITS, poses=motion.poses,
                              on_start=None if hook is TestbedRapid else motion)
        service = RwsService(ctrl, program=TestbedInstall(ctrl, motion)) \
            if hook is TestbedRapid else RwsService(ctrl)
        server = RwsServer(service).start_thread()
        made.append((server, cell))
        return twin_rws.client(server.url), ctrl, cell, motion

    yield make
    for server, cell in made:
        server.stop()
        cell.close()


def errors(entries: list[Any]) -> list[tuple[int, str]]:
    return [(e.code, e.title) for e in entries if e.msgtype == 3]


# --- the model --------------------------------------------------------------------------------
def test_inverse_kinematics_finds_the_joints_forward_kinematics_went_from() -> None:
    rng = np.random.default_rng(0)
    for side in ("left", "right"):
        m = ArmModel(side)
        for _ in range(20):
            q = rng.uniform(m.lower * 0.8, m.upper * 0.8)
            flange = m.pose(q).flange
            angle = arm_angle(m.pose(q))  # the robtarget's eax_a: not axis 7's q[2]
            s = solve(m, flange, angle, configuration(q), current=q + rng.normal(0, 5, 7))
            assert s.pose is not None, s.detail
            assert np.abs(s.pose.flange - flange).max() < 0.05
            assert arm_angle(s.pose) == pytest.approx(angle, abs=0.01)
            assert configuration(s.pose.chain_deg) == configuration(q)


def test_of_two_equally_good_solutions_the_one_nearest_the_arm_is_taken_in_any_order() -> None:
    """One pose, axis 4 a whole turn apart: the same dexterity, so which one a ConfJ-off
    MoveJ takes was the rounding's choice (a 360 deg wrist turn, and a 14 mm rise of the
    pusher, on one CPU only). It is the one nearest the arm's present joints, whatever
    order the search found them in."""
    m = ArmModel("right")
    near = m.pose([66.4, 27.3, -130.0, 34.1, -107.4, -22.9, 0.0])
    turned = m.pose([66.4, 27.3, -130.0, 34.1, 252.6, -22.9, 0.0])
    assert m.limit_violation(turned.chain_deg) is None
    for arm_at, want in (([75.8, 11.4, -130.0, 31.6, -118.0, -6.9, 0.0], near),
                         ([75.8, 11.4, -130.0, 31.6, 240.0, -6.9, 0.0], turned)):
        for found in ([near, turned], [turned, near]):
            got = _pick(m, found, None, None, free_yaw=True, prefer=arm_at)
            assert got is not None and got.chain_deg[4] == want.chain_deg[4]
        angle = arm_angle(near)  # a whole turn of axis 4 leaves it where it is
        assert arm_angle(turned) == pytest.approx(angle, abs=1e-9)
        s = solve(m, near.flange, angle, None, current=arm_at, free_yaw=True, seeds=[arm_at],
                  prefer=arm_at)
        assert s.pose is not None and abs(s.pose.chain_deg[4] - want.chain_deg[4]) < 1.0
        # ranked: the most dexterous first (at one arm angle several elbows hold the pose);
        # of this elbow's two wrists, the one nearest the arm comes first
        mine = [p for p in ranked(m, near.flange, angle, True, 12, prefer=arm_at)
                if max(abs(p.chain_deg[k] - near.chain_deg[k]) for k in range(4)) < 1.0]
        assert mine and abs(mine[0].chain_deg[4] - want.chain_deg[4]) < 1.0


def test_a_joint_moves_end_solved_again_is_the_same_and_a_new_tool_is_solved_anew() -> None:
    """The supervisor keeps the ends it solved (the IK search is a pure function of the
    joints, target, tool and rules); what it answers from them is what a supervisor that
    never solved that move answers, and a change of tool is never answered from them."""
    from sim_twin.rws.arm_supervision import ArmSupervisor
    from sim_twin.yumi_geometry import REST_JOINTS_DEG

    def fresh(tool_mm: float) -> ArmSupervisor:
        sup = ArmSupervisor({"right": "right"}, tool_mm, {"right": REST_JOINTS_DEG["right"]})
        sup.free_yaw = True
        return sup

    here = list(fresh(DEFAULT_TOOL_MM).rest["right"])
    sup = fresh(DEFAULT_TOOL_MM)
    gate = (310.0, -259.0, 100.0)
    angle = -20.0  # an arm angle the right arm holds at the gate with both tools
    first = sup._target("right", gate, angle, None, here, False)
    assert isinstance(first, list) and sup._solved
    assert first == sup._target("right", gate, angle, None, here, False)
    sup.tool_mm = DEFAULT_TOOL_MM + 40.0
    longer = sup._target("right", gate, angle, None, here, False)
    assert longer == fresh(DEFAULT_TOOL_MM + 40.0)._target("right", gate, angle, None, here,
                                                           False)
    assert isinstance(longer, list) and longer != first


def test_the_links_are_the_published_lengths() -> None:
    """ABB's modified DH of the arm: the upper arm 251.5 mm, the forearm 265 mm, the
    flange 36 mm beyond axis 6; offsets 30 and 27 mm. The joint origins must add up."""
    links = [np.asarray(xyz) for xyz, _ in _LINKS]
    assert float(links[1][1] + links[2][2]) == pytest.approx(251.5, abs=0.1)  # 2 -> 7 -> 3
    assert float(links[3][1] + links[4][2]) == pytest.approx(265.0, abs=0.01)  # 3 -> 4 -> 5
    assert float(links[5][1] + links[6][2]) == pytest.approx(36.0, abs=0.01)  # 6 -> flange
    assert (abs(links[0][0]), abs(links[4][0])) == (30.0, 27.0)


def test_the_operators_model_and_the_twins_agree_link_by_link() -> None:
    """Two models written separately from the same published numbers: every joint origin
    and the flange within 0.01 mm over random poses, both arms."""
    from drivers.yumi.irb14000 import Arm

    rng = np.random.default_rng(1)
    for side in ("left", "right"):
        ours, theirs = ArmModel(side), Arm(side)
        for _ in range(10):
            abb = rng.uniform(-60, 60, 7)
            a = ours.pose(abb_to_chain(abb)).frames
            b = theirs.pose_abb(abb).frames
            assert np.abs(a - b).max() < 0.01


# --- the arm angle: a robtarget's eax_a ---------------------------------------------------------
ROBOTSTUDIO = (  # chain joints (deg: axes 1, 2, 7, 3, 4, 5, 6); RobotStudio's arm angle with
    # the reference direction along axis 1 and along y (rpiRobotics/yumi-ik,
    # unit_tests/compare_to_robotstudio.m: Elias and Wen's figures, arXiv 2505.23111)
    ((0,) * 7, 0.0, 90.0), ((20,) * 7, 6.86, 105.54), ((30,) * 7, 14.50, 99.26),
    ((-40,) * 7, 106.67, 15.68), ((-80,) * 7, 99.01, -26.0),
    ((104, -31, 1, -18, -55, 117, 69), 19.58, -165.56),
    ((162, 1, -23, -88, 241, 98, -44), 80.07, -131.03),
    ((-20, -139, -144, 77, -263, 128, -104), 139.68, -15.92),
    ((67, -142, 121, 78, -38, 113, -194), -146.69, 119.74),
    ((-58, -138, -35, 70, -283, 133, 207), 165.86, 50.38),
)


def test_the_arm_angle_is_abbs_shoulder_elbow_wrist_angle_as_robotstudio_reports_it() -> None:
    """A robtarget's eax_a is ABB's arm angle, not axis 7: with every joint at 20 deg
    RobotStudio reports 6.86 (reference along axis 1). The twin's arm angle
    (sim_twin/sew_angle.py) gives RobotStudio's figures within 0.3 deg at 18 of the 20,
    within 3.3 at the two poses far from any the pushes use. RobotStudio's arm is the
    single-arm YuMi in its own frame (this model's, turned half a turn about axis 1)."""
    m = ArmModel("left")
    up, their_y = (0.0, 0.0, 1.0), (0.0, -1.0, 0.0)  # in the arm's own frame
    errors = [abs((arm_angle(m.pose(q), ref) - want + 180.0) % 360.0 - 180.0)
              for q, along_z, along_y in ROBOTSTUDIO
              for ref, want in ((up, along_z), (their_y, along_y))]
    assert max(errors) < 3.3, errors
    assert sum(e < 0.3 for e in errors) >= 18, errors
    assert ARM_ANGLE_REFERENCE == (0.0, 0.0, 1.0)  # the twin's controller: assumed up


def _left_line(target: tuple[float, float, float], angle_deg: float | None = None
               ) -> tuple[Any, Any, float, Any]:
    """The left arm at the gate as the driver plans it (or solved at ``angle_deg``), a
    MoveL to ``target`` holding the gate's arm angle: (the stop, the arm's track, the arm
    angle, the supervisor)."""
    from sim_twin.rws.arm_supervision import ArmSupervisor
    from sim_twin.yumi_cell import Segment, Trajectory
    from sim_twin.yumi_geometry import REST_JOINTS_DEG

    gate = (310.0, 210.0, 100.0)
    q, angle = plan("left", gate)
    if angle_deg is not None:
        got = solve(ArmModel("left"), flange_at(gate, DEFAULT_TOOL_MM), angle_deg, None)
        assert got.pose is not None, got
        q, angle = list(got.pose.chain_deg), angle_deg
    sup = ArmSupervisor({"left": "left"}, DEFAULT_TOOL_MM, {"left": REST_JOINTS_DEG["left"]})
    sup.free_yaw, sup.joints["left"] = True, q  # our RAPID: SingArea Wrist
    stop, tracks = sup.check({"left": Trajectory([Segment(gate, target, 100.0)])},
                             {"left": [{"kind": "move_l", "arm_angle_deg": angle}]})
    return stop, tracks["left"], angle, sup


def test_a_line_holds_the_arm_angle_and_axis_7_moves_as_it_must() -> None:
    """Gate to a far corner of the left table box, one eax_a: the arm angle is the same
    at every sample (within 0.01 deg) while axis 7 turns by over 40 deg (130 to about
    46): what a driver that plans with axis 7 held must know."""
    stop, track, angle, sup = _left_line((450.0, 350.0, 20.0))
    assert stop is None
    assert max(abs(sup.arm_angle("left", q) - angle) for q in track.q) < 0.01
    axis7 = [q[2] for q in track.q]
    assert max(axis7) - min(axis7) > 40.0


def test_a_line_whose_arm_angle_the_arm_cannot_hold_stops_with_the_controllers_code() -> None:
    """The gate with the elbow at arm angle 90, a MoveL to the box's far outer corner at
    clear height holding it: axis 1 passes its limit on the way, so the line stops there
    with 50027, short of the corner, the arm angle held exactly up to the stop; never
    eased (the twin once let axis 7 drift 20 deg to pass). The same line at the gate's
    own arm angle as the driver plans it runs (the test above)."""
    stop, track, angle, sup = _left_line((470.0, 370.0, 100.0), 90.0)
    assert stop is not None and (stop.code, stop.title) == (50027, "Joint Out of Range")
    assert "axis 1" in stop.detail
    tip = sup.tip("left", track.q[-1])
    assert tip[0] < 450.0 and tip[1] < 350.0, tip  # stopped on the way
    assert max(abs(sup.arm_angle("left", q) - angle) for q in track.q) < 0.01


# --- the controller refuses -------------------------------------------------------------------
def test_a_target_out_of_reach_is_the_controllers_50050(twin: Callable[..., Made]) -> None:
    c, _, cell, _ = twin()
    before = cell.tcp_xyz()["left"]
    entries = twin_rws.run(c, {"T_ROB_L": twin_rws.program([("J", (900, 300, 50), 300)])})
    assert errors(entries) == [(50050, "Position outside reach")]
    assert "mm short" in entries[-1].desc
    assert cell.tcp_xyz()["left"] == pytest.approx(before, abs=0.5)  # nothing moved


def test_a_target_only_past_a_joint_limit_is_50027(twin: Callable[..., Made]) -> None:
    """High beside the shoulder, the pusher pointing down, the elbow at arm angle 135: the
    flange is within reach, but every solution that holds that arm angle bends axis 5
    past its range (by about 26 deg with the 184.2 mm pusher, 29 with the gripper's own
    114.2 mm TCP). At arm angles from -120 to 60 the same point is reached: the arm angle
    is part of the target, and the controller never eases it to pass
    (docs/rws-checklist.md's line "A target reachable only past a joint limit")."""
    c, _, cell, _ = twin()
    m = ArmModel("left")
    target, angle = (150.0, 300.0, 300.0), 135.0
    for tool_mm in (DEFAULT_TOOL_MM, 114.2):  # what the model says of it
        s = solve(m, flange_at(target, tool_mm), angle, None)
        assert s.reason == "limit" and s.detail.startswith("axis 5 "), s
        assert solve(m, flange_at(target, tool_mm), 0.0, None).pose is not None
    before = cell.tcp_xyz()["left"]
    entries = twin_rws.run(c, {"T_ROB_L": planned_program([("J", target, angle)])})
    assert errors(entries) == [(50027, "Joint Out of Range")]
    assert "past its limit" in entries[-1].desc
    assert cell.tcp_xyz()["left"] == pytest.approx(before, abs=0.5)


def test_two_arms_driven_into_each_other_stop_at_contact(twin: Callable[..., Made]) -> None:
    """Each arm in a line from rest to its side's table at z 100 (above tb_zone_z: the
    world zones allow it anywhere), then straight towards the other's side, each target's
    arm angle that of the driver's plan there (tests/sim_twin/arm_plan.py). The real
    motion supervision trips after contact (from the motor torques), so the twin stops
    the arms where their shapes touch: not short of it (a kinder twin would hide a layout
    whose arms graze), and not through each other."""
    c, _, cell, motion = twin()

    def towards_the_other(side: str, sign: float) -> Any:
        gate, inner = (310.0, sign * 210.0, 100.0), (310.0, sign * 30.0, 100.0)
        q, at_gate = plan(side, gate)
        return planned_program([("L", gate, at_gate), ("L", inner, plan(side, inner, q)[1])])

    entries = twin_rws.run(c, {"T_ROB_L": towards_the_other("left", 1.0),
                               "T_ROB_R": towards_the_other("right", -1.0)})
    assert errors(entries) == [(50204, "Motion supervision")]
    assert "Every motion task stopped" in entries[-1].desc
    arms = motion.arms
    shapes = {a: arms.models[a].capsules(arms.models[a].pose(arms.joints[a]), arms.tool_mm)
              for a in ("left", "right")}
    gap, _, _ = clearance(shapes["left"], shapes["right"])
    assert CONTACT_MM == 0.0
    assert -0.1 <= gap <= 0.1, gap  # stopped where the links touch
    tcp = cell.tcp_xyz()
    assert tcp["left"][1] > tcp["right"][1]  # neither reached the other's side
    assert c.get_execution_state().ctrlexecstate == "stopped"


def test_an_arm_driven_into_the_table_is_stopped_by_motion_supervision(
        twin: Callable[..., Made]) -> None:
    """The pusher's tip may touch the table (the world zones watch it); the gripper that
    holds it may not: a tool 30 mm long puts the gripper's housing on the table first.
    Both lines hold the arm angle the driver holds for the left arm (-40:
    drivers/yumi/reach.py, ``ARM_ANGLE_DEG``)."""
    def down(tool_mm: float) -> Any:
        above, low = (300.0, 200.0, 120.0), (300.0, 200.0, 5.0)
        return planned_program([("L", above, -40.0), ("L", low, -40.0)], tool_mm, 50.0)

    c, _, _, _ = twin()
    entries = twin_rws.run(c, {"T_ROB_L": down(DEFAULT_TOOL_MM)})
    assert errors(entries) == [], entries  # with its real tool: fine, down to 5 mm
    c2, _, cell2, _ = twin(tool_mm=30.0)  # the same gripper, its pusher cut short
    entries = twin_rws.run(c2, {"T_ROB_L": down(30.0)})
    assert errors(entries) == [(50204, "Motion supervision")]
    assert "from the table" in entries[-1].desc
    assert cell2.tcp_xyz()["left"][2] > 5.0 + 10.0  # stopped well above the target


def test_the_librarys_movej_keeps_its_configuration_or_is_50080(twin: Callable[..., Made]
                                                                 ) -> None:
    """ConfJ is on in the library's RAPID: a MoveJ to a target in a configuration the arm
    cannot take there is refused; the same target in the configuration the arm reaches it
    in runs."""
    c, _, cell, _ = twin(CellMotion)
    m = ArmModel("left")
    target = (330.0, 200.0, 60.0)
    angle = plan("left", target)[1]  # the arm angle of the driver's plan there
    down = np.diag([-1.0, 1.0, -1.0])  # twin_rws.DOWN: a half turn about y
    right = configuration(solve(m, flange_at(target, DEFAULT_TOOL_MM, down), angle,
                                None).pose.chain_deg)  # type: ignore[union-attr]
    wrong = (right[0] + 2, right[1], right[2])
    exec_client = mpe.MotionProgramExecClient(abb_client=c)

    def prog(conf: tuple[int, int, int]) -> Any:
        frame = mpe.pose([0, 0, DEFAULT_TOOL_MM], [1, 0, 0, 0])  # the cell's pusher
        mp = mpe.MotionProgram(tool=mpe.tooldata(True, frame,
                                                 mpe.loaddata(0.1, [0, 0, 50], [1, 0, 0, 0],
                                                              0, 0, 0)))
        mp.MoveJ(mpe.robtarget(list(target), twin_rws.DOWN, mpe.confdata(*conf, 0),
                               [angle] + [9e9] * 5), mpe.v500, mpe.fine)
        return mp

    with pytest.raises(Exception, match="Motion Program Failed"):
        exec_client.execute_motion_program(prog(wrong), task="T_ROB_L")
    entry = c.read_event_log()[0]
    assert (entry.code, entry.title) == (50080, "Position not compatible")
    c.resetpp()
    exec_client.execute_motion_program(prog(right), task="T_ROB_L")
    assert cell.tcp_xyz()["left"] == pytest.approx(target, abs=1.0)
    assert arm_angle(m.pose(cell_joints(c))) == pytest.approx(angle, abs=0.1)


def cell_joints(c: Any) -> list[float]:
    """The left arm's chain joints as the controller reports them (its jointtarget: axis 7
    in ``eax_a``)."""
    j = c.get_jointtarget("ROB_L")
    return abb_to_chain([*j.robax.tolist(), float(j.extax[0])])


# --- the rest pose ------------------------------------------------------------------------------
def test_the_rest_pose_is_folded_clear_of_the_table_the_other_arm_and_the_camera() -> None:
    """ABB's folded arm and wrist, axis 1 swung back 40 deg, axis 2 at -90
    (sim_twin/yumi_geometry.py REST_JOINTS_DEG): with the 184.2 mm pusher the twin's model
    holds the tip behind the robot's front and high, far from the zones, the other arm
    and every joint limit, and outside the camera's frame with the driver's 2 % margin
    (ABB's home itself, [0, -130, 30, 0, 40, 0, +-135], hangs the tip in the picture)."""
    from sim_twin.yumi_arms import CHAIN_AXES, LIMITS_DEG, table_clearance
    from sim_twin.yumi_geometry import HEIGHT, REST_JOINTS_DEG, CameraModel

    assert REST_JOINTS_DEG == {"left": (40.0, -90.0, 30.0, 0.0, 40.0, 0.0, 135.0),
                               "right": (-40.0, -90.0, 30.0, 0.0, 40.0, 0.0, -135.0)}
    cam = CameraModel.default()
    shapes = {}
    for side, sign in (("left", 1.0), ("right", -1.0)):
        m, q = ArmModel(side), abb_to_chain(REST_JOINTS_DEG[side])
        tip, flange = m.tip(q, DEFAULT_TOOL_MM), m.pose(q).flange[:3, 3]
        assert tip == pytest.approx((-117.0, sign * 276.0, 268.0), abs=2.0)
        assert flange.tolist() == pytest.approx([-155.0, sign * 253.0, 447.0], abs=2.0)
        shapes[side] = m.capsules(m.pose(q), DEFAULT_TOOL_MM)
        assert table_clearance(shapes[side])[0] > 300.0  # every link (the twin's: 348)
        assert tip[2] > 80.0 + 20.0 + 150.0  # far above tb_zone_z + 20
        margin = min(min(a - LIMITS_DEG[ax][0], LIMITS_DEG[ax][1] - a)
                     for a, ax in zip(q, CHAIN_AXES, strict=True))
        assert margin > 33.0
        v = cam.project((tip[0], tip[1], 0.0))[0][1]  # the driver's table-plane projection
        assert v > HEIGHT * 1.02 + 70.0  # 77 px past the frame's 2 % margin
        assert cam.project(tip)[0][1] > HEIGHT  # the tip itself: off the picture
        home = ArmModel(side).tip(abb_to_chain((0, -130, 30, 0, 40, 0, sign * 135)),
                                  DEFAULT_TOOL_MM)
        assert 0 < cam.project((home[0], home[1], 0.0))[0][1] < HEIGHT  # ABB's: in view
    assert clearance(shapes["left"], shapes["right"])[0] > 30.0  # the shoulders: 35 mm


def test_the_joint_path_from_rest_to_the_gate_stays_over_the_zones() -> None:
    """By joints from rest to (310, +-210, 100), the pusher down (the driver's first
    move, to the gate's joints as its model plans them): outside the zone box the tip
    stays above tb_zone_z + 20, every link over 150 mm above the table."""
    from sim_twin.rws.world_zones import default_zone
    from sim_twin.yumi_arms import table_clearance
    from sim_twin.yumi_geometry import REST_JOINTS_DEG

    for side, sign in (("left", 1.0), ("right", -1.0)):
        m, zone = ArmModel(side), default_zone(side)
        q0 = np.array(abb_to_chain(REST_JOINTS_DEG[side]))
        gate = np.array(plan(side, (310.0, sign * 210.0, 100.0))[0])
        for f in np.linspace(0.0, 1.0, 101):
            q = q0 + f * (gate - q0)
            x, y, z = m.tip(q, DEFAULT_TOOL_MM)
            if not (zone.x0 < x < zone.x1 and zone.y0 < y < zone.y1):
                assert z >= zone.zone_z + 20.0, (side, f, (x, y, z))
            assert table_clearance(m.capsules(m.pose(q), DEFAULT_TOOL_MM))[0] > 150.0


def test_the_overhead_camera_sees_no_pusher_at_rest(twin: Callable[..., Made]) -> None:
    """The twin's arms rest the pushers where the rest joints hold them: its picture shows
    no marker, the pusher's body and cap project below the frame, and a move to the table
    brings the marker into view (ABB's home would leave both in the picture)."""
    import cv2

    _, _, cell, motion = twin()
    assert cell.tcp_xyz()["left"] == pytest.approx(motion.arms.tip("left"), abs=1.0)
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    at_rest = cell.render(noise=False)
    _, ids, _ = det.detectMarkers(at_rest)
    assert ids is None or len(ids) == 0
    for arm, tcp in cell.tcp_xyz().items():  # the pusher's body and its cap: off the picture
        body = [(tcp[0] + dx, tcp[1] + dy, tcp[2] + dz) for dx in (-22, 22) for dy in (-22, 22)
                for dz in (0.0, 30.0)]
        uv = cell.camera.project(body)
        assert (uv[:, 1] > cell.camera.height).all(), (arm, uv)
    cell.execute({"left": [{"kind": "move_l", "xyz_mm": [310.0, 210.0, 100.0],
                            "speed_mm_s": 500.0, "fine": True}]})
    _, ids, _ = det.detectMarkers(cell.render(noise=False))
    assert ids is not None and ids.ravel().tolist() == [0]
