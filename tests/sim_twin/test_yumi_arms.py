"""The hardware twin's arms: the IRB 14000's kinematics, and its controller refusing what
the robot refuses, with the controller's codes.

Through the UNCHANGED ABB client against a real ``TestbedRapid`` twin (our RAPID's start
hook on a real ``YumiTwinCell``): a target out of reach (50050), a target reachable only
past a joint limit (50027), two arms driven into each other (50204, stopped before the
links touch, every task), an arm driven into the table (50204), and a MoveJ whose
configuration the arm cannot keep (50080, ConfJ on: the library's RAPID). The model
itself: forward and inverse kinematics agree, the link lengths are the published ones,
and the operator's model (``drivers/yumi/irb14000.py``, written separately from the same
numbers) puts every link where the twin's does.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
import twin_rws
from abb_motion_program_exec import abb_motion_program_exec_client as mpe

from sim_twin.rws import Irc5Controller, RwsServer
from sim_twin.rws.arm_supervision import CONTACT_MM, flange_at
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.motion_exec import CellMotion
from sim_twin.rws.rws_service import RwsService
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
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
            s = solve(m, flange, float(q[2]), configuration(q), current=q + rng.normal(0, 5, 7))
            assert s.pose is not None, s.detail
            assert np.abs(s.pose.flange - flange).max() < 0.05
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
        s = solve(m, near.flange, -130.0, None, free_yaw=True, seeds=[arm_at], prefer=arm_at)
        assert s.pose is not None and abs(s.pose.chain_deg[4] - want.chain_deg[4]) < 1.0
        first = ranked(m, near.flange, -130.0, True, prefer=arm_at)[0]
        assert abs(first.chain_deg[4] - want.chain_deg[4]) < 1.0


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
    first = sup._target("right", gate, -130.0, None, here, False)
    assert isinstance(first, list) and sup._solved
    assert first == sup._target("right", gate, -130.0, None, here, False)
    sup.tool_mm = DEFAULT_TOOL_MM + 40.0
    longer = sup._target("right", gate, -130.0, None, here, False)
    assert longer == fresh(DEFAULT_TOOL_MM + 40.0)._target("right", gate, -130.0, None, here,
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


# --- the controller refuses -------------------------------------------------------------------
def test_a_target_out_of_reach_is_the_controllers_50050(twin: Callable[..., Made]) -> None:
    c, _, cell, _ = twin()
    before = cell.tcp_xyz()["left"]
    entries = twin_rws.run(c, {"T_ROB_L": twin_rws.program([("J", (900, 300, 50), 300)])})
    assert errors(entries) == [(50050, "Position outside reach")]
    assert "mm short" in entries[-1].desc
    assert cell.tcp_xyz()["left"] == pytest.approx(before, abs=0.5)  # nothing moved


def test_a_target_only_past_a_joint_limit_is_50027(twin: Callable[..., Made]) -> None:
    """High and close to the body, the pusher pointing down: the flange is within reach,
    but every solution bends axis 5 past its range (with the 184.2 mm pusher and with the
    gripper's own 114.2 mm TCP alike; the operator's model says the same,
    tests/drivers/test_yumi_kinematics.py)."""
    c, _, cell, _ = twin()
    m = ArmModel("left")
    target = (200.0, 300.0, 400.0)
    for tool_mm in (DEFAULT_TOOL_MM, 114.2):  # what the model says of it
        s = solve(m, flange_at(target, tool_mm), twin_rws.ARM_ANGLE_DEG["left"], None)
        assert s.reason == "limit" and s.detail.startswith("axis 5 "), s
    before = cell.tcp_xyz()["left"]
    entries = twin_rws.run(c, {"T_ROB_L": twin_rws.program([("J", target, 300)])})
    assert errors(entries) == [(50027, "Joint Out of Range")]
    assert "past its limit" in entries[-1].desc
    assert cell.tcp_xyz()["left"] == pytest.approx(before, abs=0.5)


def test_two_arms_driven_into_each_other_stop_before_contact(twin: Callable[..., Made]
                                                             ) -> None:
    """Each arm by joints from rest to its side's table at z 100 (above tb_zone_z: the
    world zones allow it anywhere; a joint move from rest straight to the table's inner
    edge would dip into them first), then straight towards the other's side."""
    c, _, cell, motion = twin()
    entries = twin_rws.run(c, {"T_ROB_L": twin_rws.program([("J", (310, 210, 100), 300),
                                                            ("L", (310, 30, 100), 100)]),
                               "T_ROB_R": twin_rws.program([("J", (310, -210, 100), 300),
                                                            ("L", (310, -30, 100), 100)])})
    assert errors(entries) == [(50204, "Motion supervision")]
    assert "Every motion task stopped" in entries[-1].desc
    arms = motion.arms
    shapes = {a: arms.models[a].capsules(arms.models[a].pose(arms.joints[a]), arms.tool_mm)
              for a in ("left", "right")}
    gap, _, _ = clearance(shapes["left"], shapes["right"])
    assert 0.0 <= gap < CONTACT_MM + 20.0  # stopped just before the links touch
    tcp = cell.tcp_xyz()
    assert tcp["left"][1] > tcp["right"][1]  # neither reached the other's side
    assert c.get_execution_state().ctrlexecstate == "stopped"


def test_an_arm_driven_into_the_table_is_stopped_by_motion_supervision(
        twin: Callable[..., Made]) -> None:
    """The pusher's tip may touch the table (the world zones watch it); the gripper that
    holds it may not: a tool 30 mm long puts the gripper's housing on the table first."""
    c, _, _, _ = twin()
    short = twin_rws.program([("J", (300, 200, 120), 300), ("L", (300, 200, 5), 50)],
                             tool_z_mm=DEFAULT_TOOL_MM)
    entries = twin_rws.run(c, {"T_ROB_L": short})
    assert errors(entries) == [], entries  # with its real tool: fine, down to 5 mm
    c2, _, cell2, _ = twin(tool_mm=30.0)  # the same gripper, its pusher cut short
    entries = twin_rws.run(c2, {"T_ROB_L": twin_rws.program(
        [("J", (300, 200, 120), 300), ("L", (300, 200, 5), 50)], tool_z_mm=30.0)})
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
    down = np.diag([-1.0, 1.0, -1.0])  # twin_rws.DOWN: a half turn about y
    right = configuration(solve(m, flange_at(target, DEFAULT_TOOL_MM, down), 150.0,
                                None).pose.chain_deg)  # type: ignore[union-attr]
    wrong = (right[0] + 2, right[1], right[2])
    exec_client = mpe.MotionProgramExecClient(abb_client=c)

    def prog(conf: tuple[int, int, int]) -> Any:
        frame = mpe.pose([0, 0, DEFAULT_TOOL_MM], [1, 0, 0, 0])  # the cell's pusher
        mp = mpe.MotionProgram(tool=mpe.tooldata(True, frame,
                                                 mpe.loaddata(0.1, [0, 0, 50], [1, 0, 0, 0],
                                                              0, 0, 0)))
        mp.MoveJ(mpe.robtarget(list(target), twin_rws.DOWN, mpe.confdata(*conf, 0),
                               [150.0] + [9e9] * 5), mpe.v500, mpe.fine)
        return mp

    with pytest.raises(Exception, match="Motion Program Failed"):
        exec_client.execute_motion_program(prog(wrong), task="T_ROB_L")
    entry = c.read_event_log()[0]
    assert (entry.code, entry.title) == (50080, "Position not compatible")
    c.resetpp()
    exec_client.execute_motion_program(prog(right), task="T_ROB_L")
    assert cell.tcp_xyz()["left"] == pytest.approx(target, abs=1.0)


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
    move): outside the zone box the tip stays above tb_zone_z + 20 (the twin: 118 and
    125 mm), every link over 150 mm above the table."""
    from sim_twin.rws.world_zones import default_zone
    from sim_twin.yumi_arms import table_clearance
    from sim_twin.yumi_geometry import REST_JOINTS_DEG

    for side, sign in (("left", 1.0), ("right", -1.0)):
        m, zone = ArmModel(side), default_zone(side)
        q0 = np.array(abb_to_chain(REST_JOINTS_DEG[side]))
        s = solve(m, flange_at((310.0, sign * 210.0, 100.0), DEFAULT_TOOL_MM),
                  sign * 130.0, None, free_yaw=True, seeds=[list(q0)])
        assert s.pose is not None, s
        for f in np.linspace(0.0, 1.0, 101):
            q = q0 + f * (np.array(s.pose.chain_deg) - q0)
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
