"""The RWS twin runs abb_motion_program_exec's programs: the binary file decoded as the
library writes it (every command kind, the header, malformed files refused with the
controller's error), and the UNCHANGED client over HTTP against a twin serving a real
YumiTwinCell: the arm's TCP at the target (RWS get_robtarget with the program's tool, and
the cell), the commanded speed, the rest pose, the library's MultiMove file clash with the
YuMi's task names, a stop mid-motion, and a malformed program's event-log entry."""

from __future__ import annotations

import itertools
import math
import os
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import twin_rws
from abb_motion_program_exec import abb_motion_program_exec_client as mpe
from abb_robot_client.rws import RWS
from arm_plan import plan
from arm_plan import program as planned_program

from sim_twin.rws import Irc5Controller, MechUnit, RwsServer, serve
from sim_twin.rws.arm_supervision import flange_at
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.motion_exec import CellMotion, arc_points
from sim_twin.rws.motion_program import (
    CirPathMode,
    ConfData,
    EGMMoveC,
    EGMMoveL,
    EGMRunJoint,
    EGMRunPose,
    JointTarget,
    LoadData,
    MoveAbsJ,
    MoveC,
    MoveJ,
    MoveL,
    Pose,
    ProgramFileError,
    RobTarget,
    SpeedData,
    SyncMoveOff,
    SyncMoveOn,
    ToolData,
    WaitTime,
    WobjData,
    ZoneData,
    decode_program,
    program_file_for_task,
)
from sim_twin.yumi_arms import DEFAULT_TOOL_MM, ArmModel, abb_to_chain, rest_tip
from sim_twin.yumi_cell import ACCEL_MM_S2, YumiTwinCell
from sim_twin.yumi_ik import configuration, solve

REST_TIP = {side: rest_tip(side) for side in ("left", "right")}
"""Where the twin's arms rest the pusher's tip (their rest joints, its 184.2 mm tool)."""

ROOT = Path(__file__).resolve().parents[2]
PUSHER_MM = DEFAULT_TOOL_MM  # the twin's pusher (184.2 mm), as the library's tool
DOWN = [0.0, 0.0, 1.0, 0.0]
CONF = mpe.confdata(0, 0, 0, 4)
EXT = [0.0] + [9e9] * 5
LOAD = mpe.loaddata(0.001, [0, 0, 0.001], [1, 0, 0, 0], 0, 0, 0)


DOWN_ROT = np.diag([-1.0, 1.0, -1.0])
"""The flange's rotation of the quaternion DOWN (a half turn about y)."""


def rt(x: float, y: float, z: float, side: str = "left", tool_z: float = PUSHER_MM,
       base: tuple[float, float, float] | None = None, angle: float | None = None) -> Any:
    """A tool-down robtarget with the arm angle ``angle`` (``eax_a``: ABB's, not axis 7's;
    default :data:`ELBOW_UP`) in the configuration the twin's arm reaches it in (what a lab
    reads off the robtarget after jogging there: the library's RAPID keeps ConfJ on);
    ``base``: the target in the base frame when the program's work object moves it."""
    bx, by, bz = base or (x, y, z)
    angle = ELBOW_UP[side] if angle is None else angle
    pose = solve(ArmModel(side), flange_at((bx, by, bz), tool_z, DOWN_ROT), angle, None).pose
    c1, c4, c6 = (0, 0, 0) if pose is None else configuration(pose.chain_deg)
    return mpe.robtarget([x, y, z], DOWN, mpe.confdata(c1, c4, c6, 0), [angle] + [9e9] * 5)


ELBOW_UP = {"left": 176.0, "right": -176.0}
"""The arm angle of the elbow-up posture (axis 7 near 0) these tests' arms reach their
targets in: the one they took when the twin read ``eax_a`` as axis 7 (at 0)."""


def tool(z_mm: float) -> Any:
    return mpe.tooldata(True, mpe.pose([0, 0, z_mm], [1, 0, 0, 0]), LOAD)


def tool_rapid(z_mm: float) -> str:
    return f"[TRUE,[[0,0,{z_mm:g}],[1,0,0,0]],[0.001,[0,0,0.001],[1,0,0,0],0,0,0]]"


def client(url: str) -> RWS:
    """The unchanged ABB client, with a timeout on its requests (it sets none)."""
    c = RWS(url)
    plain = c._session.request
    c._session.request = lambda m, u, **k: plain(m, u, **{"timeout": 20, **k})  # type: ignore[method-assign]
    return c


# --- decoding ---------------------------------------------------------------------------------
def every_command() -> Any:
    """A program with every command kind and a non-default header; values float32-exact."""
    t = mpe.tooldata(True, mpe.pose([1.5, -2.0, 120.25], [0.5, 0.5, 0.5, 0.5]),
                     mpe.loaddata(0.25, [1, 2, 3], [1, 0, 0, 0], 0.5, 0.25, 0.125))
    w = mpe.wobjdata(False, True, "ROB_L", mpe.pose([300, 0, 10], [1, 0, 0, 0]),
                     mpe.pose([0, 5, 0], [0, 0, 0, 1]))
    mp = mpe.MotionProgram(first_cmd_num=7, tool=t, wobj=w, timestamp="2026-01-02-03-04-05-0607",
                           seqno=42, gripload=mpe.loaddata(2.0, [0, 0, 50], [1, 0, 0, 0], 0, 0, 0))
    a = mpe.robtarget([400, 200.5, 50], DOWN, mpe.confdata(1, -1, 2, 4), [-135.5] + [9e9] * 5)
    b = mpe.robtarget([410, 210, 60.75], [0, 1, 0, 0], CONF, EXT)
    mp.MoveAbsJ(mpe.jointtarget([0, -130, 30, 0, 40, 0], [-135, 9e9, 9e9, 9e9, 9e9, 9e9]),
                mpe.v100, mpe.fine)
    mp.MoveJ(a, mpe.v500, mpe.z10)
    mp.MoveL(b, mpe.speeddata(37.5, 250, 5000, 1000), mpe.z1)
    mp.MoveC(a, b, mpe.v20, mpe.z50)
    mp.WaitTime(0.25)
    mp.CirPathMode(mpe.CirPathModeSwitch.Wrist46)
    mp.SyncMoveOn()
    mp.SyncMoveOff()
    mp.EGMRunJoint(10, 0.5, 0.25)
    mp.EGMRunPose(10, 0.5, 0.25, mpe.pose([1, 2, 3], [1, 0, 0, 0]))
    mp.EGMMoveL(b, mpe.v5, mpe.fine)
    mp.EGMMoveC(a, b, mpe.v5, mpe.z0)
    return mp


def test_every_command_kind_decodes_to_the_values_given() -> None:
    p = decode_program(every_command().get_program_bytes())
    assert (p.version, p.timestamp, p.seqno, p.egm.kind) == (10011, "2026-01-02-03-04-05-0607",
                                                             42, "none")
    assert p.tool == ToolData(True, Pose((1.5, -2.0, 120.25), (0.5, 0.5, 0.5, 0.5)),
                              LoadData(0.25, (1, 2, 3), (1, 0, 0, 0), 0.5, 0.25, 0.125))
    assert p.wobj == WobjData(False, True, "ROB_L", Pose((300, 0, 10), (1, 0, 0, 0)),
                              Pose((0, 5, 0), (0, 0, 0, 1)))
    assert p.gripload == LoadData(2.0, (0, 0, 50), (1, 0, 0, 0), 0, 0, 0)
    f9 = struct.unpack("<f", struct.pack("<f", 9e9))[0]  # RAPID's 9E+09 in float32
    a = RobTarget((400, 200.5, 50), (0, 0, 1, 0), ConfData(1, -1, 2, 4), (-135.5,) + (f9,) * 5)
    b = RobTarget((410, 210, 60.75), (0, 1, 0, 0), ConfData(0, 0, 0, 4), (0.0,) + (f9,) * 5)
    v100, v500, v20, v5 = (SpeedData(v, 500, 5000, 1000) for v in (100, 500, 20, 5))
    fine = ZoneData(True, 0, 0, 0, 0, 0, 0)
    z = struct.unpack("<3f", struct.pack("<3f", 0.3, 0.03, 1.5))
    assert p.commands == (
        MoveAbsJ(7, JointTarget((0, -130, 30, 0, 40, 0), (-135,) + (f9,) * 5), v100, fine),
        MoveJ(8, a, v500, ZoneData(False, 10, 15, 15, z[2], 15, z[2])),
        MoveL(9, b, SpeedData(37.5, 250, 5000, 1000), ZoneData(
            False, 1, 1, 1, struct.unpack("<f", struct.pack("<f", 0.1))[0], 1,
            struct.unpack("<f", struct.pack("<f", 0.1))[0])),
        MoveC(10, a, b, v20, ZoneData(False, 50, 75, 75, 7.5, 75, 7.5)),
        WaitTime(11, 0.25), CirPathMode(12, 5), SyncMoveOn(13), SyncMoveOff(14),
        EGMRunJoint(15, 10, 0.5, 0.25), EGMRunPose(16, 10, 0.5, 0.25, Pose((1, 2, 3),
                                                                           (1, 0, 0, 0))),
        EGMMoveL(17, b, v5, fine),
        EGMMoveC(18, a, b, v5, ZoneData(False, z[0], z[0], z[0], z[1], z[0], z[1])),
    )


def test_egm_configurations_decode() -> None:
    mm = mpe.egm_minmax(-0.5, 0.5)
    configs = [
        (mpe.EGMStreamConfig(), "none", 0),  # the writer encodes stream-only as none
        (mpe.EGMJointTargetConfig(mm, mm, mm, mm, mm, mm, 10.0, 20.0), "joint_target", 14),
        (mpe.EGMPoseTargetConfig(mpe.pose([1, 2, 3], [1, 0, 0, 0]), mpe.egmframetype.EGM_FRAME_WOBJ,
                                 mpe.pose([0, 0, 0], [1, 0, 0, 0]),
                                 mpe.egmframetype.EGM_FRAME_TOOL, mm, mm, mm, mm, mm, mm, 1, 2),
         "pose_target", 30),
        (mpe.EGMPathCorrectionConfig(mpe.pose([4, 5, 6], [1, 0, 0, 0])), "path_correction", 7),
    ]
    for cfg, kind, n in configs:
        mp = mpe.MotionProgram(egm_config=cfg)
        mp.EGMMoveL(rt(400, 200, 50), mpe.v50, mpe.fine)
        p = decode_program(mp.get_program_bytes())
        assert (p.egm.kind, len(p.egm.values)) == (kind, n)
        assert isinstance(p.commands[0], EGMMoveL) and p.commands[0].cmd_num == 1
    assert decode_program(mpe.MotionProgram(egm_config=configs[2][0]).get_program_bytes()
                          ).egm.values[7] == 2.0  # EGM_FRAME_WOBJ


def test_a_tasks_program_file_is_the_one_the_client_uploads() -> None:
    mp = mpe.MotionProgram()
    mp.WaitTime(1)
    for task in ("T_ROB1", "T_ROB2", "T_ROB_L", "T_ROB_R", "T_ROB12"):
        uploaded, _ = mpe._get_motion_program_file("$RAMDISK", mp, task)
        assert program_file_for_task(task) == uploaded.replace("$RAMDISK/", "RAMDISK:")
    assert program_file_for_task("T_ROB_L") == program_file_for_task("T_ROB_R")


def _patched(data: bytes, index: int, value: float) -> bytes:
    """``data`` with its float number ``index`` replaced."""
    return data[:4 * index] + struct.pack("<f", value) + data[4 * index + 4:]


HEADER_FLOATS = 1 + 19 + (2 + 9 + 14) + 11 + 9 + 1 + 1
"""version, tooldata, wobjdata (robhold, ufprog, a string of 1 + 8 floats, 2 poses),
loaddata, the timestamp string, seqno, the EGM kind."""


@pytest.mark.parametrize(("patch", "reason"), [
    (lambda b: b"", "Motion program file empty"),
    (lambda b: _patched(b, 0, 10010), "Invalid motion program file version"),
    (lambda b: b[:30], "Motion program file truncated"),
    (lambda b: b[:-6], "Motion program file truncated"),
    (lambda b: _patched(b, HEADER_FLOATS + 1, 99), "Invalid motion program command"),
    (lambda b: _patched(b, HEADER_FLOATS + 1, 3.5), "Invalid number in motion program"),
    (lambda b: _patched(b, HEADER_FLOATS + 2 + 17 + 4, 0.5), "Invalid bool in motion program"),
    (lambda b: _patched(b, 1, float("nan")), "Invalid number in motion program"),
    (lambda b: _patched(b, 1 + 19 + 2, 40), "Invalid string in motion program"),
    (lambda b: _patched(b, HEADER_FLOATS - 1, 7), "Invalid EGM configuration"),
])
def test_a_malformed_file_is_a_rapid_error(patch: Callable[[bytes], bytes], reason: str) -> None:
    mp = mpe.MotionProgram()
    mp.MoveL(rt(400, 200, 50), mpe.v100, mpe.fine)
    good = mp.get_program_bytes()
    assert len(good) == 4 * (HEADER_FLOATS + 2 + 17 + 4 + 7)
    with pytest.raises(ProgramFileError) as info:
        decode_program(patch(good), "RAMDISK:motion_program.bin")
    e = info.value
    assert (e.code, e.title, e.reason) == (80001, "Motion Program Failed", reason)
    assert e.args[0] == "Motion Program Failed" and len(e.args) == 5  # the client reads 5
    assert e.args[2] == "RAMDISK:motion_program.bin"


def test_cir_path_mode_switch_is_checked_and_arcs_pass_the_circle_point() -> None:
    mp = mpe.MotionProgram()
    mp.CirPathMode(mpe.CirPathModeSwitch.PathFrame)
    with pytest.raises(ProgramFileError, match="CirPathMode"):
        decode_program(_patched(mp.get_program_bytes(), HEADER_FLOATS + 2, 9))
    pts = arc_points((0.0, 0.0, 0.0), (10.0, 10.0, 0.0), (20.0, 0.0, 0.0))  # a half circle
    assert len(pts) == 18 and pts[-1] == (20.0, 0.0, 0.0)
    assert all(math.dist(p, (10.0, 0.0, 0.0)) == pytest.approx(10.0) for p in pts)
    assert max(p[1] for p in pts) == pytest.approx(10.0)
    with pytest.raises(ValueError):
        arc_points((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (2.0, 0.0, 0.0))


# --- on a real cell, through the unchanged client ----------------------------------------------
Twin = tuple[RwsServer, Irc5Controller, YumiTwinCell, CellMotion, threading.Lock]


@pytest.fixture
def cell_twin() -> Iterator[Callable[..., Twin]]:
    made: list[tuple[RwsServer, YumiTwinCell]] = []

    def make(realtime: float = 0.0, units: tuple[MechUnit, ...] = YUMI_UNITS) -> Twin:
        cell = YumiTwinCell(3, realtime=realtime)
        lock = threading.Lock()
        motion = CellMotion(cell, lock, units, pusher_length_mm=PUSHER_MM)
        ctrl = Irc5Controller(units=units, poses=motion.poses, on_start=motion)
        for u in units:
            ctrl.symbols.declare(u.task, "user", "pusher", "tooldata", tool_rapid(PUSHER_MM))
            ctrl.symbols.declare(u.task, "user", "short", "tooldata", tool_rapid(60.0))
        server = serve(ctrl)
        made.append((server, cell))
        return server, ctrl, cell, motion, lock

    yield make
    for server, cell in made:
        server.stop()
        cell.close()


def tcp(cell: YumiTwinCell, lock: threading.Lock, arm: str) -> tuple[float, float, float]:
    with lock:  # waits for a motion still holding the cell
        return cell.tcp_xyz()[arm]


def test_movel_moves_the_arm_tcp_to_the_target_of_the_programs_tool(cell_twin: Any) -> None:
    s, ctrl, cell, _, lock = cell_twin()
    m = mpe.MotionProgramExecClient(abb_client=client(s.url))
    m.enable_motion_logging()
    right_before = tcp(cell, lock, "right")
    mp = mpe.MotionProgram(tool=tool(PUSHER_MM))
    mp.MoveJ(rt(400, 200, 80), mpe.v500, mpe.z10)
    mp.MoveL(rt(400, 200, 30), mpe.v100, mpe.fine)
    log = m.execute_motion_program(mp, task="T_ROB_L")
    got = tcp(cell, lock, "left")
    assert got == pytest.approx((400, 200, 30), abs=1.0)  # tool z = the pusher: TCP = tip
    tip = m.abb_client.get_robtarget("ROB_L", tool="pusher")  # the arm's joints say it
    assert tip.trans.tolist() == pytest.approx(list(got), abs=0.1)  # (the pusher sags)
    assert tip.rot.tolist() == pytest.approx(DOWN)
    flange = m.abb_client.get_robtarget("ROB_L")  # tool0
    assert flange.trans[2] == pytest.approx(got[2] + PUSHER_MM, abs=0.1)
    assert tcp(cell, lock, "right") == right_before
    assert log.column_headers == ["timestamp", "ROB_L_cmd_num", "ROB_L_x", "ROB_L_y", "ROB_L_z"]
    assert set(log.data[:, 1].tolist()) == {1.0, 2.0}
    assert log.data[-1, 2:].tolist() == pytest.approx([400, 200, 30], abs=1.0)
    assert [f["_title"] for f in ctrl.files.listdir("$TEMP")] == ["motion_program.bin"]
    # a tool of 60 mm on the 184.2 mm pusher: the pusher's bottom ends 124.2 mm below
    mp = mpe.MotionProgram(tool=tool(60.0))
    mp.MoveL(rt(420, 180, 160, tool_z=60.0), mpe.v200, mpe.fine)
    m.execute_motion_program(mp, task="T_ROB_L")
    assert tcp(cell, lock, "left") == pytest.approx((420, 180, 160 - (PUSHER_MM - 60)), abs=1.0)
    short = m.abb_client.get_robtarget("ROB_L", tool="short")
    assert short.trans.tolist() == pytest.approx([420, 180, 160], abs=1.0)


def test_the_commanded_speed_and_the_work_object(cell_twin: Any) -> None:
    s, _, cell, _, lock = cell_twin()
    m = mpe.MotionProgramExecClient(abb_client=client(s.url))
    m.enable_motion_logging()
    table = mpe.wobjdata(False, True, "", mpe.pose([300, 0, 0], [1, 0, 0, 0]),
                         mpe.pose([0, 0, 0], [1, 0, 0, 0]))
    start = REST_TIP["right"]
    mp = mpe.MotionProgram(tool=tool(PUSHER_MM), wobj=table)
    mp.MoveJ(rt(100, -200, 100, "right", base=(400, -200, 100)), mpe.v200, mpe.fine)
    log = m.execute_motion_program(mp, task="T_ROB_R")
    assert tcp(cell, lock, "right") == pytest.approx((400, -200, 100), abs=1.0)
    length = math.dist(start, (400, -200, 100))
    chord = length / 200 + 200 / ACCEL_MM_S2  # the cell's trapezoid at 200 mm/s
    arrived = next(r[0] for r in log.data if math.dist(r[2:], (400, -200, 100)) < 1.0)
    # a MoveJ's TCP follows the joints' curve, longer than the chord, at most v_tcp
    # (issue 43, sim_twin/rws/speed_bounds.py): it arrives later than the chord's time
    assert arrived > chord
    rows = log.data[log.data[:, 0] <= arrived]
    fastest = max(math.dist(b[2:], a[2:]) / (b[0] - a[0])
                  for a, b in itertools.pairwise(rows) if b[0] > a[0])
    assert 150.0 < fastest <= 200.0 * 1.01
    m.abb_client.set_speedratio(50)  # the speed ratio scales every speed
    mp = mpe.MotionProgram(tool=tool(PUSHER_MM))
    mp.MoveL(rt(400, -300, 100, "right"), mpe.v200, mpe.fine)
    log = m.execute_motion_program(mp, task="T_ROB_R")
    arrived = next(r[0] for r in log.data if math.dist(r[2:], (400, -300, 100)) < 1.0)
    assert arrived == pytest.approx(100 / 100 + 100 / ACCEL_MM_S2, abs=0.1)


def test_moveabsj_to_the_reported_joints_is_the_rest_other_joints_move_there_or_50027(
        cell_twin: Any) -> None:
    """A MoveAbsJ goes where its joints put the arm (the rest, read off the controller, or
    any other joints within the axes' ranges); joints past a range are the controller's
    50027, nothing moves."""
    s, _, cell, _, lock = cell_twin()
    m = mpe.MotionProgramExecClient(abb_client=client(s.url))
    mp = mpe.MotionProgram(tool=tool(PUSHER_MM))
    mp.MoveJ(rt(400, 200, 60), mpe.v500, mpe.fine)
    j = m.abb_client.get_jointtarget("ROB_L")  # the pose the twin reports: its rest
    mp.MoveAbsJ(mpe.jointtarget(j.robax.tolist(), j.extax.tolist()), mpe.v500, mpe.fine)
    m.execute_motion_program(mp, task="T_ROB_L")
    assert tcp(cell, lock, "left") == pytest.approx(REST_TIP["left"], abs=1.0)
    other = [10.0, *j.robax.tolist()[1:]]  # axis 1 swung 10 deg further
    mp = mpe.MotionProgram(tool=tool(PUSHER_MM))
    mp.MoveAbsJ(mpe.jointtarget(other, j.extax.tolist()), mpe.v100, mpe.fine)
    m.execute_motion_program(mp, task="T_ROB_L")
    there = ArmModel("left").tip(abb_to_chain([*other, j.extax[0]]), PUSHER_MM)
    assert tcp(cell, lock, "left") == pytest.approx(there, abs=1.0)
    assert m.abb_client.get_jointtarget("ROB_L").robax.tolist() == pytest.approx(other, abs=0.01)
    bad = mpe.MotionProgram(tool=tool(PUSHER_MM))
    bad.MoveAbsJ(mpe.jointtarget([10, -150, 30, 0, 40, 0], j.extax.tolist()), mpe.v100, mpe.fine)
    with pytest.raises(Exception, match="Motion Program Failed"):
        m.execute_motion_program(bad, task="T_ROB_L")
    entry = m.abb_client.read_event_log()[0]
    assert (entry.code, entry.msgtype, entry.title) == (50027, 3, "Joint Out of Range")
    assert "axis 2" in entry.desc  # -150: past axis 2's -143.5
    assert tcp(cell, lock, "left") == pytest.approx(there, abs=1.0)
    assert m.abb_client.get_execution_state().ctrlexecstate == "stopped"


def test_multimove_with_the_yumis_task_names_runs_one_file_on_both_arms(cell_twin: Any) -> None:
    """The library's bug (not the twin's): it names a task's file after the task's
    trailing digits; T_ROB_L and T_ROB_R have none, so both programs are uploaded to
    motion_program.bin, the right's last. Both tasks then read that one file: the left
    arm's program is lost and the left arm runs the RIGHT arm's program."""
    s, ctrl, cell, motion, lock = cell_twin()
    m = mpe.MotionProgramExecClient(abb_client=client(s.url))
    left_before = tcp(cell, lock, "left")
    left = mpe.MotionProgram(tool=tool(PUSHER_MM))
    left.MoveL(rt(400, 200, 60), mpe.v500, mpe.fine)
    right = mpe.MotionProgram(tool=tool(PUSHER_MM))
    right.WaitTime(0.2)
    m.execute_multimove_motion_program([left, right], ["T_ROB_L", "T_ROB_R"])  # no error
    assert sorted(motion.last_run) == ["T_ROB_L", "T_ROB_R"]
    read = {t: (tp.path, tp.program) for t, tp in motion.last_run.items()}
    assert read["T_ROB_L"] == read["T_ROB_R"]  # one file, one program, for both tasks
    assert read["T_ROB_L"][0] == "RAMDISK:motion_program.bin"
    assert read["T_ROB_L"][1] == decode_program(right.get_program_bytes())
    assert tcp(cell, lock, "left") == left_before  # the left arm never got its MoveL
    assert [f["_title"] for f in ctrl.files.listdir("$TEMP")] == ["motion_program.bin"]


def test_multimove_with_numbered_tasks_moves_both_arms_at_once(cell_twin: Any) -> None:
    units = (MechUnit("ROB_1", "T_ROB1", "left"), MechUnit("ROB_2", "T_ROB2", "right"))
    s, _, cell, motion, lock = cell_twin(units=units)
    m = mpe.MotionProgramExecClient(abb_client=client(s.url))
    m.enable_motion_logging()
    mps = []
    for y in (200, -200):
        mp = mpe.MotionProgram(tool=tool(PUSHER_MM))
        mp.SyncMoveOn()
        mp.MoveJ(rt(400, y, 60, "left" if y > 0 else "right"), mpe.v500, mpe.fine)
        mp.SyncMoveOff()
        mps.append(mp)
    log = m.execute_multimove_motion_program(mps, ["T_ROB1", "T_ROB2"])
    assert {t: tp.path for t, tp in motion.last_run.items()} == {
        "T_ROB1": "RAMDISK:motion_program.bin", "T_ROB2": "RAMDISK:motion_program2.bin"}
    assert tcp(cell, lock, "left") == pytest.approx((400, 200, 60), abs=1.0)
    assert tcp(cell, lock, "right") == pytest.approx((400, -200, 60), abs=1.0)
    assert log.column_headers[1::4] == ["ROB_1_cmd_num", "ROB_2_cmd_num"]
    mid = log.data[len(log.data) // 3]  # both arms on their way in one sample: together
    assert math.dist(mid[2:5], REST_TIP["left"]) > 10
    assert math.dist(mid[6:9], REST_TIP["right"]) > 10


@pytest.mark.slow  # a paced line of about 3.5 s
def test_a_stop_mid_motion_leaves_the_pusher_between_start_and_target(cell_twin: Any) -> None:
    s, _, cell, _, lock = cell_twin(realtime=1.0)  # paced: the line takes ~3.5 s
    c = client(s.url)
    m = mpe.MotionProgramExecClient(abb_client=c)
    start, target = (310.0, 300.0, 100.0), (310.0, 100.0, 100.0)
    first = mpe.MotionProgram(tool=tool(PUSHER_MM))  # by joints from rest to the start
    first.MoveJ(rt(*start, angle=plan("left", start)[1]), mpe.v500, mpe.fine)
    m.execute_motion_program(first, task="T_ROB_L")
    assert tcp(cell, lock, "left") == pytest.approx(start, abs=1.0)
    mp = mpe.MotionProgram(tool=tool(PUSHER_MM))
    mp.MoveL(rt(*target, angle=plan("left", target)[1]), mpe.v60, mpe.fine)
    seq = m.execute_motion_program(mp, task="T_ROB_L", wait=False)
    deadline = time.monotonic() + 20
    while math.dist(c.get_robtarget("ROB_L", tool="pusher").trans.tolist(), start) < 20:
        assert time.monotonic() < deadline, "the pusher never left its start"  # read mid-motion
        time.sleep(0.02)
    c.stop()
    assert c.get_execution_state().ctrlexecstate == "stopped"
    held = tcp(cell, lock, "left")  # the hook has let go of the cell
    along, total = math.dist(held, start), math.dist(start, target)
    assert 20 <= along < total - 50
    off_line = [held[i] - start[i] - (target[i] - start[i]) * along / total for i in range(3)]
    assert math.hypot(*off_line) < 1.0
    # the controller reads its joints; the cell's pusher trails them by about 1 mm at 60 mm/s
    assert c.get_robtarget("ROB_L", tool="pusher").trans.tolist() == pytest.approx(list(held),
                                                                                    abs=1.5)
    with pytest.raises(Exception, match="Could not find log file messages"):  # never closed
        m.read_motion_program_result_log(seq)
    nxt = mpe.MotionProgram(tool=tool(PUSHER_MM))  # the next program starts where it stopped
    after = (held[0], held[1] - 10, held[2])
    nxt.MoveL(rt(*after, angle=plan("left", after)[1]), mpe.v200, mpe.fine)
    m.enable_motion_logging()
    log = m.execute_motion_program(nxt, task="T_ROB_L")
    assert math.dist(log.data[0, 2:], held) < 3.0  # no jump back to the old start
    assert tcp(cell, lock, "left") == pytest.approx((held[0], held[1] - 10, held[2]), abs=1.0)


def test_a_malformed_program_fails_with_the_controllers_elog_entry(cell_twin: Any) -> None:
    class Garbled(mpe.MotionProgram):  # type: ignore[misc]
        def get_program_bytes(self, seqno: int | None = None) -> bytes:
            return _patched(super().get_program_bytes(seqno), HEADER_FLOATS + 1, 99)

    s, _, cell, _, lock = cell_twin()
    m = mpe.MotionProgramExecClient(abb_client=client(s.url))
    before = tcp(cell, lock, "left")
    mp = Garbled(tool=tool(PUSHER_MM))
    mp.MoveL(rt(400, 200, 60), mpe.v500, mpe.fine)
    with pytest.raises(Exception, match=r"Invalid motion program command "
                                        r"RAMDISK:motion_program.bin unknown opcode 99"):
        m.execute_motion_program(mp, task="T_ROB_L")
    entry = m.abb_client.read_event_log()[0]
    assert (entry.code, entry.msgtype, entry.title) == (80001, 3, "Motion Program Failed")
    assert entry.args[:2] == ["Motion Program Failed", "Invalid motion program command"]
    assert tcp(cell, lock, "left") == before
    assert m.abb_client.get_tasks()["T_ROB_L"].excstate == "stopped"
    below = mpe.MotionProgram(tool=tool(PUSHER_MM))  # a target the cell cannot reach
    below.MoveL(rt(400, 200, -5), mpe.v100, mpe.fine)
    with pytest.raises(Exception, match="Position outside reach"):
        m.execute_motion_program(below, task="T_ROB_L")


@pytest.mark.parametrize("rapid", ["library", "testbed"])
def test_python_m_sim_twin_rws_cell_runs_programs(tmp_path: Path, rapid: str) -> None:
    port_file = tmp_path / "port"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "sim_twin.rws", "--port", "0",
                             "--port-file", str(port_file), "--cell", "--arms", "left",
                             "--pusher-length-mm", "100",
                             *(["--rapid", rapid] if rapid == "library" else [])],
                            cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while not port_file.exists():
            assert proc.poll() is None and time.monotonic() < deadline, "twin did not start"
            time.sleep(0.05)
        c = client(f"http://127.0.0.1:{int(port_file.read_text())}")
        if rapid == "library":
            mp = mpe.MotionProgram()  # tool0: the flange
            mp.MoveJ(rt(400, 200, 150, tool_z=0.0), mpe.v500, mpe.fine)
            mpe.MotionProgramExecClient(abb_client=c).execute_motion_program(mp, task="T_ROB_L")
        else:  # the default: our RAPID, its own file, its symbols; the file's tool frame
            # must be tool_pusher's (the twin ships it as its pusher, 100 mm here)
            above, q = (400.0, 200.0, 120.0), plan("left", (400.0, 200.0, 120.0),
                                                    tool_z_mm=100.0)
            mp = planned_program([("J", above, q[1]),  # by joints above the target, then down
                                  ("L", (400.0, 200.0, 50.0),
                                   plan("left", (400.0, 200.0, 50.0), q[0], 100.0)[1])], 100.0)
            assert [e.title for e in twin_rws.run(c, {"T_ROB_L": mp})] == ["Testbed Motion Done"]
            assert c.get_rapid_variable("tb_zone_z", "T_ROB_L/TestbedTask_L") == "80"
        assert c.get_robtarget("ROB_L").trans.tolist() == pytest.approx([400, 200, 150], abs=1.0)
        proc.terminate()
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
