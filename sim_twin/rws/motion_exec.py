"""The RWS twin's RAPID side: the start hook that runs ``abb_motion_program_exec``'s
uploaded programs on a :class:`~sim_twin.yumi_cell.YumiTwinCell`.

Why it exists: the agent drives the YuMi through the unchanged library, whose RAPID
module reads the program file of each started motion task, moves the arm, writes a log
file and says so in the event log; the client then reads those. For the rehearsal to run
that path before the robot, the twin must do the same with the bytes the client sent: this
hook (``Irc5Controller(on_start=CellMotion(...))``) does, and moves the cell's pushers at
the commanded speeds.

What a run does (a task is an arm: ``T_ROB_L`` -> ``left``, ``T_ROB_R`` -> ``right``):

1. Each started motion task reads ITS file (:func:`program_file_for_task`: on a YuMi
   both tasks read ``motion_program.bin``, the library's naming; both arms then run the
   same program, as the twin assumes the library's RAPID would) and decodes it; a file
   that cannot be read is an ErrWrite 80001 "Motion Program Failed" entry.
2. The commands become cell waypoints: a robtarget is the TCP of the program's tool in
   its work object; the twin turns it into the pusher's bottom (flange = TCP minus the
   tool's ``tframe``, the flange pointing down; cell TCP = flange minus the pusher's
   length, as :class:`~sim_twin.rws.cell_link.CellPoses` reports it). The arms
   (:class:`~sim_twin.rws.arm_supervision.ArmSupervisor`) solve every target: a MoveL's
   TCP moves in a straight line, a MoveJ's and a MoveAbsJ's joints move evenly from the
   arm's to the target's and the pusher goes where they put it (a curve), a MoveAbsJ to
   any joints within the axes' ranges (past one: 50027); MoveC is a chain of chords
   through the circle point. What they cannot do is the controller's own error (50050,
   50027, 50080, 50026, 50204). Refused (80001, the task named): a moving work object or
   a stationary tool, a target below the table, a speed <= 0, EGM (no EGM channel).
   Speeds are scaled by the controller's speed ratio (at least 1 %) and capped at the
   YuMi's 1500 mm/s, as a controller caps ``vmax``, or at VelSet's Max (:meth:`CellMotion.velset`:
   our RAPID's ``tb_v_tcp_max``). Every move runs at most as fast as its speeddata allows,
   the TCP of a joint move along its curve, the tool's turn at v_ori and axis 7 at v_reax
   included (:func:`sim_twin.rws.speed_bounds.within_speeds`, issue 43).
   Zones, CirPathMode and SyncMoveOn/Off are read and not modelled (every point is a stop
   point; the arms move at the same time but are not path-synchronised).
3. Both arms' blocks of moves run in one ``cell.execute`` (MultiMove); a WaitTime holds
   its arm and, until it ends, the other arm's next block too (the twin runs in rounds).
4. The log: ``log-<program timestamp>.bin`` on the RAM disk (the format the client
   unpacks: version, timestamp, header, float32 rows) and the two ErrWrite \\I entries
   (80003, "Motion Program Log File Opened" naming the file, "... Closed"). Rows are
   sampled every ``frame_every_s`` simulated seconds while ``motion_program_log_motion``
   is 1: ``timestamp`` (s since the run began) and per task ``<unit>_cmd_num``,
   ``<unit>_x``, ``_y``, ``_z`` (the program tool's TCP, base frame, mm; the twin has no
   joint angles to log). With logging off the file has the header only.
5. ``stop`` (or motors off, a guard stop, a mode change) is seen at the next sample: the
   motion ends there, each pusher held at its commanded point of that moment; the log is
   left open (no "Closed" entry), as a program stopped mid-instruction leaves it.

While a motion runs the cell's lock is held; RWS reads positions from the snapshot the
hook keeps (refreshed every sample), so ``get_robtarget`` answers during the motion.

Over 450 lines, on purpose: it is the twin's reading of ABB's RAPID motion module, every
command with its checks beside its motion; split, a command's refusal would sit away
from the move it guards.
"""

from __future__ import annotations

import contextlib
import math
import re
import struct
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from sim_twin.constants import TIME_STEP_S
from sim_twin.rws.arm_supervision import ArmStop, ArmSupervisor
from sim_twin.rws.cell_link import CellPoses
from sim_twin.rws.errors import RwsError
from sim_twin.rws.event_log import MSG_INFO
from sim_twin.rws.irc5 import ProgramRun, RapidError
from sim_twin.rws.mechunits import (
    TOOL_DOWN,
    YUMI_UNITS,
    MechUnit,
    Quat,
    Vec3,
    qconj,
    qmul,
    qnorm,
    qrot,
)
from sim_twin.rws.motion_program import (
    ERRWRITE_INFO,
    FILE_VERSION,
    CirPathMode,
    Command,
    EGMMoveC,
    EGMMoveL,
    EGMRunJoint,
    EGMRunPose,
    MotionProgramFile,
    MoveAbsJ,
    MoveC,
    MoveJ,
    MoveL,
    ProgramFileError,
    RobTarget,
    SpeedData,
    SyncMoveOff,
    SyncMoveOn,
    ToolData,
    WaitTime,
    WobjData,
    decode_program,
    describe,
    program_failed,
    program_file_for_task,
)
from sim_twin.rws.speed_bounds import within_speeds
from sim_twin.rws.world_zones import ArmZone
from sim_twin.yumi_arms import DEFAULT_TOOL_MM, abb_to_chain
from sim_twin.yumi_cell import MAX_SPEED_MM_S, Trajectory, YumiTwinCell
from sim_twin.yumi_geometry import REST_JOINTS_DEG

LOG_OPENED, LOG_CLOSED = "Motion Program Log File Opened", "Motion Program Log File Closed"
ORIENT_TOLERANCE_DEG = 1.0
CHORD_DEG = 10.0
"""A MoveC arc becomes chords of at most this angle (at least 4)."""
Waypoint = dict[str, Any]


@dataclass
class _Block:
    """Consecutive moves of one arm: cell waypoints and the cmd_num of each."""

    waypoints: list[Waypoint] = field(default_factory=list)
    cmd_nums: list[int] = field(default_factory=list)


@dataclass(frozen=True)
class _Wait:
    t: float
    cmd_num: int


@dataclass(frozen=True)
class TaskProgram:
    """What one task of a run read: its file and the decoded program."""

    task: str
    unit: MechUnit
    path: str
    program: MotionProgramFile


class _Halted(Exception):
    """Raised from the cell's frame callback when the run is stopped."""


# --- targets -----------------------------------------------------------------------------------
def _compose(a: tuple[Vec3, Quat], b: tuple[Sequence[float], Sequence[float]]
             ) -> tuple[Vec3, Quat]:
    (p, q), (t, r) = a, b
    d = qrot(q, t)
    return (p[0] + d[0], p[1] + d[1], p[2] + d[2]), qnorm(qmul(q, r))


def _angle_deg(a: Quat, b: Quat) -> float:
    dot = min(1.0, abs(sum(x * y for x, y in zip(a, b, strict=True))))
    return math.degrees(2.0 * math.acos(dot))


def _unit_quat(q: Sequence[float], what: str, task: str) -> Quat:
    n = math.sqrt(sum(c * c for c in q))
    if abs(n - 1.0) > 1e-3:
        raise program_failed("Orientation not normalised", f"{what}: |q| = {n:.6g}", task=task)
    return qnorm(q)


def tool_offset(tool: ToolData, pusher_length_mm: float) -> Vec3:
    """The program tool's TCP minus the cell's TCP (the pusher's bottom), base frame,
    with the tool pointing down (the pushes; a tool turned otherwise: the arms'
    :meth:`~sim_twin.rws.arm_supervision.ArmSupervisor.tool_point`)."""
    d = qrot(TOOL_DOWN, tool.tframe.trans)
    return (d[0], d[1], d[2] + pusher_length_mm)


def cell_point(target: RobTarget, tool: ToolData, wobj: WobjData, pusher_length_mm: float,
               *, task: str, what: str) -> Vec3:
    """The cell TCP that puts the program tool's TCP at ``target`` (see the docstring)."""
    return cell_pose(target, tool, wobj, pusher_length_mm, task=task, what=what)[0]


def cell_pose(target: RobTarget, tool: ToolData, wobj: WobjData, pusher_length_mm: float,
              *, task: str, what: str) -> tuple[Vec3, list[list[float]]]:
    """The cell TCP (the pusher's tip: ``pusher_length_mm`` along the flange's z) and the
    flange's rotation (3x3 rows) that put the program tool's TCP at ``target`` in its
    orientation: any orientation (a MoveL from rest may keep the rest's), the flange being
    the target's frame less the tool's ``tframe``."""
    if not tool.robhold:
        raise program_failed("Stationary tool not supported by the twin", what, task=task)
    if wobj.robhold or not wobj.ufprog or wobj.ufmec:
        raise program_failed("Moving work object not supported by the twin",
                             f"{what}: robhold={wobj.robhold}, ufprog={wobj.ufprog}, "
                             f"ufmec={wobj.ufmec!r}", task=task)
    frame = _compose(((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)),
                     (wobj.uframe.trans, _unit_quat(wobj.uframe.rot, "uframe", task)))
    frame = _compose(frame, (wobj.oframe.trans, _unit_quat(wobj.oframe.rot, "oframe", task)))
    p, q = _compose(frame, (target.trans, _unit_quat(target.rot, what, task)))
    tq = _unit_quat(tool.tframe.rot, "tframe", task)
    flange_q = qnorm(qmul(q, qconj(tq)))
    d = qrot(flange_q, tool.tframe.trans)
    z = qrot(flange_q, (0.0, 0.0, 1.0))
    out = tuple(p[k] - d[k] + z[k] * pusher_length_mm for k in range(3))
    if out[2] < 0.0:
        raise program_failed("Position outside reach",
                             f"{what}: the pusher would be {-out[2]:.1f} mm below the table",
                             task=task)
    cols = [qrot(flange_q, e) for e in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))]
    return out, [[cols[j][i] for j in range(3)] for i in range(3)]  # type: ignore[return-value]


def _speed(s: SpeedData, ratio: float, task: str, what: str) -> float:
    if not s.v_tcp > 0.0:
        raise program_failed("Invalid speed", f"{what}: v_tcp = {s.v_tcp:g}", task=task)
    return min(s.v_tcp * max(ratio, 1.0) / 100.0, MAX_SPEED_MM_S)


def arc_points(a: Vec3, b: Vec3, c: Vec3) -> list[Vec3]:
    """Chords of the circle from ``a`` through ``b`` to ``c`` (ends included but ``a``);
    ``ValueError`` if the three points are (nearly) on one line."""
    u = [b[i] - a[i] for i in range(3)]
    v = [c[i] - a[i] for i in range(3)]

    def cross(x: Sequence[float], y: Sequence[float]) -> list[float]:
        return [x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]]

    w = cross(u, v)
    ww = sum(x * x for x in w)
    uu, vv = sum(x * x for x in u), sum(x * x for x in v)
    if ww < 1e-9 * max(uu * vv, 1e-12) or uu < 1e-6 or vv < 1e-6:
        raise ValueError("the circle point and the end point are on a line with the start")
    vw, wu = cross(v, w), cross(w, u)
    centre = [a[i] + (uu * vw[i] + vv * wu[i]) / (2.0 * ww) for i in range(3)]
    r_vec = [a[i] - centre[i] for i in range(3)]
    r = math.sqrt(sum(x * x for x in r_vec))
    n = [x / math.sqrt(ww) for x in w]
    e1 = [x / r for x in r_vec]
    e2 = cross(n, e1)
    rel = [c[i] - centre[i] for i in range(3)]
    sweep = math.atan2(sum(x * y for x, y in zip(rel, e2, strict=True)),
                       sum(x * y for x, y in zip(rel, e1, strict=True))) % (2.0 * math.pi)
    k = max(4, math.ceil(math.degrees(sweep) / CHORD_DEG))
    pts: list[Vec3] = []
    for i in range(1, k):
        t = sweep * i / k
        pts.append(tuple(centre[j] + r * (math.cos(t) * e1[j] + math.sin(t) * e2[j])
                         for j in range(3)))  # type: ignore[arg-type]
    return [*pts, c]


# --- programs -> waypoints ------------------------------------------------------------------
@dataclass
class _ArmContext:
    tp: TaskProgram
    here: Vec3
    rest_joints: tuple[float, ...]
    rest_xyz: Vec3
    pusher_length_mm: float
    ratio: float
    conf_j: bool = True
    """ConfJ on: a MoveJ keeps its target's configuration (our RAPID sets it)."""
    tip_of: Callable[[Sequence[float]], Vec3] | None = None
    """The cell TCP the arm's joints (ABB order) put the pusher at (the twin's arms)."""
    v_max: float = MAX_SPEED_MM_S
    """VelSet's Max (mm/s): no move's TCP runs faster (at 100 % speed ratio)."""


def _moves(ctx: _ArmContext, cmd: Command) -> list[Waypoint]:
    """The waypoints of one move command (updates ``ctx.here``)."""
    task, what, prog = ctx.tp.task, describe(cmd), ctx.tp.program
    if isinstance(cmd, EGMRunJoint | EGMRunPose | EGMMoveL | EGMMoveC):
        raise program_failed("EGM not available on the twin", what, task=task)
    if isinstance(cmd, MoveAbsJ):
        return [_joint_waypoint(ctx, cmd, what)]
    assert isinstance(cmd, MoveJ | MoveL | MoveC)
    v = _speed(cmd.speed, ctx.ratio, task, what)
    end, rot = cell_pose(cmd.to_point, prog.tool, prog.wobj, ctx.pusher_length_mm, task=task,
                         what=what)
    if isinstance(cmd, MoveC):
        via = cell_point(cmd.cir_point, prog.tool, prog.wobj, ctx.pusher_length_mm,
                         task=task, what=f"{what} (circle point)")
        try:
            pts = arc_points(ctx.here, via, end)
        except ValueError as exc:
            raise program_failed("Circle not defined", f"{what}: {exc}", task=task) from None
    else:
        pts = [end]
    kind = "move_j" if isinstance(cmd, MoveJ) else "move_l"
    ctx.here = end
    arm = _arm_of(cmd.to_point, kind == "move_j" and ctx.conf_j)
    return [{"kind": kind, "xyz_mm": list(p), "speed_mm_s": v, "rot": rot,
             "fine": cmd.zone.finep if p is end else False, **arm} for p in pts]


def _joint_waypoint(ctx: _ArmContext, cmd: MoveAbsJ, what: str) -> Waypoint:
    """A MoveAbsJ, as RAPID accepts it: any joint target (axes 1-6 in ``robax``, axis 7 in
    ``eax_a``), not only the rest (issue 43: the twin refused every other one, the robot
    runs them). The arms move every joint linearly from where they are to it and judge
    it as the controller does (``ArmSupervisor``): an axis past its range, an unset 9E9
    included, is the controller's 50027 "Joint Out of Range" before anything moves; the
    path on the way is supervised (world zones, 50204 contact). The pusher goes where the
    joints put it. (A NaN never gets here: the file is refused on reading.)"""
    task = ctx.tp.task
    j = cmd.to_joint_pos
    want = (*j.robax, j.extax[0])
    speed = _speed(cmd.speed, ctx.ratio, task, what)
    if ctx.tip_of is None:  # every CellMotion gives its arms: a caller that does not
        raise program_failed("Joint target without the twin's arms", what, task=task)
    ctx.here = ctx.tip_of(want)
    return {"kind": "move_j", "xyz_mm": list(ctx.here), "fine": cmd.zone.finep,
            "speed_mm_s": speed, "joints_deg": list(want), "arm_angle_deg": want[6]}


def _arm_of(target: RobTarget, conf_on: bool) -> dict[str, Any]:
    """What the arm supervision reads of a robtarget: its arm angle (axis 7, the first
    external axis on a YuMi; an unset 9E9 keeps the arm's), its configuration and
    whether the controller must keep it (MoveJ with ConfJ on)."""
    out: dict[str, Any] = {"conf": [target.robconf.cf1, target.robconf.cf4,
                                    target.robconf.cf6], "conf_on": conf_on}
    if target.extax and abs(target.extax[0]) < 9e8:
        out["arm_angle_deg"] = float(target.extax[0])
    return out


def arm_plan(ctx: _ArmContext) -> list[_Block | _Wait]:
    """One arm's program as blocks of moves and waits."""
    out: list[_Block | _Wait] = []
    for cmd in ctx.tp.program.commands:
        if isinstance(cmd, CirPathMode | SyncMoveOn | SyncMoveOff):
            continue
        if isinstance(cmd, WaitTime):
            if cmd.t < 0.0:
                raise program_failed("Invalid WaitTime", f"{describe(cmd)}: {cmd.t:g} s",
                                     task=ctx.tp.task)
            out.append(_Wait(cmd.t, cmd.cmd_num))
            continue
        wps = [_bounded(wp, cmd, ctx) for wp in _moves(ctx, cmd)]
        if not out or not isinstance(out[-1], _Block):
            out.append(_Block())
        block = out[-1]
        assert isinstance(block, _Block)
        block.waypoints += wps
        block.cmd_nums += [cmd.cmd_num] * len(wps)
    return out


def _bounded(wp: Waypoint, cmd: Command, ctx: _ArmContext) -> Waypoint:
    """A move's speed bounds, at the controller's speed ratio: its TCP speed at most
    VelSet's Max (``ctx.v_max``), and the speeddata's v_ori and v_reax (deg/s), which
    :func:`sim_twin.rws.speed_bounds.within_speeds` holds every move to."""
    s = getattr(cmd, "speed", None)
    if s is None:
        return wp
    scale = max(ctx.ratio, 1.0) / 100.0
    return {**wp, "speed_mm_s": min(float(wp["speed_mm_s"]), ctx.v_max * scale),
            "v_ori_deg_s": s.v_ori * scale, "v_reax_deg_s": s.v_reax * scale}


# --- the log -------------------------------------------------------------------------------------
def _f32(v: float) -> bytes:
    return struct.pack("<f", v)


def _log_str(s: str) -> bytes:
    raw = s.encode("ascii")
    return _f32(len(raw)) + raw


class _Log:
    """The run's log file and its two event log entries."""

    def __init__(self, run: ProgramRun, programs: Sequence[TaskProgram], enabled: bool,
                 offsets: Mapping[str, Vec3]) -> None:
        first = programs[0]
        stamp = re.sub(r"[^0-9-]", "", first.program.timestamp) or "0"
        self.name = f"log-{stamp}.bin"
        self.run, self.programs, self.enabled = run, list(programs), enabled
        self.offsets = dict(offsets)
        self.timestamp = first.program.timestamp
        self.columns = ["timestamp"] + [f"{tp.unit.name}_{c}" for tp in programs
                                        for c in ("cmd_num", "x", "y", "z")]
        self.rows: list[list[float]] = []
        self.task = first.task

    def _entry(self, header: str, reason: str) -> None:
        self.run.controller.elog.write(ERRWRITE_INFO, MSG_INFO, header,
                                       args=(header, reason, "", "", ""), src_name=self.task)

    def open(self) -> None:
        self.write_file()
        self._entry(LOG_OPENED, f"RAMDISK:{self.name}")

    def sample(self, t: float, cmd_nums: Mapping[str, int],
               tcps: Mapping[str, Sequence[float]]) -> None:
        if not self.enabled:
            return
        row = [t]
        for tp in self.programs:
            arm = tp.unit.arm
            o, p = self.offsets[tp.task], tcps[arm]
            row += [float(cmd_nums.get(arm, 0)), p[0] + o[0], p[1] + o[1], p[2] + o[2]]
        self.rows.append(row)

    def write_file(self) -> None:
        body = b"".join(_f32(v) for row in self.rows for v in row)
        data = _f32(FILE_VERSION) + _log_str(self.timestamp) + \
            _log_str(",".join(self.columns)) + body
        self.run.controller.files.put(f"RAMDISK:{self.name}", data)

    def close(self) -> None:
        self.write_file()
        self._entry(LOG_CLOSED, f"RAMDISK:{self.name}")


# --- the hook -------------------------------------------------------------------------------
def _set_signal(run: ProgramRun, name: str, value: float) -> None:
    with contextlib.suppress(RwsError):  # a twin configured without the library's signals
        run.controller.signals.write(name, value)


def _signal(run: ProgramRun, name: str) -> float:
    try:
        return run.controller.signals.value(name)
    except RwsError:
        return 0.0


class _Clock:
    """The simulated time of one ``cell.execute``, replayed from its frame callbacks (the
    cell calls back at the first step ``i`` with ``i * dt >= next``, then ``next += dt_f``)."""

    def __init__(self, frame_every_s: float) -> None:
        self.every, self.next, self.step = frame_every_s, frame_every_s, 0

    def tick(self) -> float:
        i = self.step + 1
        while i * TIME_STEP_S < self.next:
            i += 1
        self.step, self.next = i, self.next + self.every
        return i * TIME_STEP_S


class _ZoneHit(Exception):
    """Raised from the cell's frame callback at a planned stop (a world zone, the arms)."""


class ControllerStop(RapidError):
    """An error of the controller itself (its kinematics, its motion supervision), not
    one a RAPID module writes: it reaches the event log with its own code and title."""


_CAUSES: dict[str, str] = {
    "reach": "The target is farther from the arm's shoulder than the arm reaches with "
             "this tool and arm angle.",
    "limit": "The target is reachable only with a joint past its working range.",
    "conf": "The target cannot be reached in the programmed configuration (confdata).",
    "singular": "The linear path passes close to a singular arm configuration.",
    "contact": "The arm met the other arm or the table: the motion supervision tripped.",
}
_ACTIONS: dict[str, str] = {
    "reach": "Move the workspace closer to the arm or shorten the tool (testbed check "
             "reports each corner's reach).",
    "limit": "Change the arm angle or the target's orientation.",
    "conf": "Program the target's configuration as the arm reaches it (jog there and "
            "read the robtarget), or turn ConfJ off.",
    "singular": "Use MoveJ, or change the arm angle or the path.",
    "contact": "Jog the arms apart and check the workspaces, rest poses and paths "
               "(testbed check reports the arms' clearance).",
}


@dataclass(frozen=True)
class ZoneStop:
    """A planned world-zone stop: at ``t`` (s into the move) ``arm``'s TCP reaches ``box``
    (the box's ``name`` and corners: the zone the RAPID defined)."""

    t: float
    arm: str
    box: Any
    point: tuple[float, float, float] | None = None
    """The TCP of the tool in use where it stops (on the zone's face)."""


class _Sampler:
    """The cell's frame callback for one ``cell.execute``: every ``every`` simulated
    seconds it samples the log, refreshes the positions RWS reads, publishes a camera
    frame when one is due, and stops the motion at a stop request or at ``stop_at``."""

    def __init__(self, motion: CellMotion, run: ProgramRun, blocks: Mapping[str, _Block],
                 trajs: Mapping[str, Trajectory], log: _Log | None, t0: float, lead: str,
                 every: float, stop_at: float | None) -> None:
        self.motion, self.run, self.blocks, self.log = motion, run, blocks, log
        self.t0, self.lead, self.stop_at = t0, lead, stop_at
        self.clock = _Clock(every)
        self.ends = {a: list(_cumulative(s.duration for s in trajs[a].segments)) for a in trajs}
        self.last_t = 0.0
        self._shown = 0.0

    def __call__(self) -> None:
        t = self.last_t = self.clock.tick()
        if self.stop_at is not None and t >= self.stop_at:
            raise _ZoneHit
        nums = {a: _cmd_at(self.ends[a], b.cmd_nums, t) for a, b in self.blocks.items()}
        tcps = self.motion._refresh()
        if self.log is not None:
            self.log.sample(self.t0 + t, nums, tcps)
        if self.lead in nums:
            _set_signal(self.run, "motion_program_current_cmd_num", float(nums[self.lead]))
        if self.motion.on_frame is not None and t - self._shown >= self.motion.on_frame_every_s:
            self._shown = t
            self.motion._publish()
        if self.run.stop_requested.is_set():
            raise _Halted


class CellMotion:
    """The start hook: ``Irc5Controller(units=units, poses=motion.poses, on_start=motion)``.

    ``cell`` and ``cell_lock`` are the cell and the lock everything else that touches it
    holds; ``pusher_length_mm`` is the flange's height above the cell's TCP (as
    :class:`CellPoses`). ``frame_every_s``: how often (simulated seconds) the hook samples
    the log, refreshes the positions RWS reads and looks for a stop. ``last_run`` holds
    what each task of the latest run read (the twin's side: tests, the lab).

    ``on_frame`` (optional, e.g. a camera's publish): called with the cell lock held at
    most every ``on_frame_every_s`` simulated seconds while the arms move (at the samples)
    and once when a run's motion has ended, before execution reads stopped."""

    conf_j = True
    """ConfJ on: a MoveJ keeps its target's configuration (50080 if it cannot)."""
    sing_area_wrist = False
    """SingArea\\Wrist: the tool may turn about its own axis near a wrist singularity."""

    def __init__(self, cell: YumiTwinCell, cell_lock: threading.Lock | threading.RLock,
                 units: Sequence[MechUnit] = YUMI_UNITS, *,
                 pusher_length_mm: float = DEFAULT_TOOL_MM,
                 frame_every_s: float = 0.02, on_frame: Callable[[], None] | None = None,
                 on_frame_every_s: float = 0.0) -> None:
        if frame_every_s < TIME_STEP_S:
            raise ValueError(f"frame_every_s must be >= one physics step ({TIME_STEP_S:g} s)")
        self.cell, self.cell_lock = cell, cell_lock
        self.units = tuple(u for u in units if u.arm in cell.arms)
        self.pusher_length_mm = float(pusher_length_mm)
        self.frame_every_s = float(frame_every_s)
        self.on_frame, self.on_frame_every_s = on_frame, float(on_frame_every_s)
        self._snap_lock = threading.Lock()
        with cell_lock:
            self._snap = dict(cell.tcp_xyz())
        self.arms = ArmSupervisor({a: cell.sides[a] for a in cell.arms}, self.pusher_length_mm,
                                  {a: REST_JOINTS_DEG[cell.sides[a]] for a in cell.arms})
        self.arms.free_yaw = self.sing_area_wrist
        with cell_lock:  # the pushers rest where the arms' rest joints hold them
            for arm in cell.arms:
                cell.set_rest(arm, self.arms.tip(arm))
        self.poses = CellPoses(self, threading.Lock(), self.units, self.pusher_length_mm,
                               arms=self.arms)
        self.last_run: dict[str, TaskProgram] = {}
        self.tools: dict[str, Vec3] = {}
        """Each arm's tool in use (its tframe's translation) in the latest plans: the TCP
        the world zones watch."""
        if not hasattr(self, "zones"):
            self.zones: dict[str, ArmZone] = {}
            """The stationary world zones per arm (the library's RAPID defines none; our
            RAPID's hook, ``TestbedRapid``, sets them)."""

    def _tip_of(self, arm: str, joints_abb: Sequence[float]) -> Vec3:
        return self.arms.tip(arm, abb_to_chain(joints_abb))

    def tcp_xyz(self) -> dict[str, tuple[float, float, float]]:
        """The cell's TCPs; while a motion holds the cell, the latest sample's."""
        if self.cell_lock.acquire(blocking=False):
            try:
                self._refresh()
            finally:
                self.cell_lock.release()
        with self._snap_lock:
            return dict(self._snap)

    def _refresh(self) -> dict[str, tuple[float, float, float]]:
        """Read the cell (its lock held) into the snapshot."""
        tcps = self.cell.tcp_xyz()
        with self._snap_lock:
            self._snap = dict(tcps)
        return tcps

    # --- a run ---------------------------------------------------------------------------
    def velset(self, task: str) -> float:
        """VelSet's Max of ``task`` (mm/s): the library's RAPID sets none, so the
        controller's own (the YuMi's top TCP speed); our RAPID's hook sets its cap."""
        return MAX_SPEED_MM_S

    def program_file(self, task: str) -> str:
        """The file ``task`` reads: the library's naming (a variant overrides it)."""
        return program_file_for_task(task)

    def _load(self, run: ProgramRun) -> list[TaskProgram]:
        out = []
        for task in run.tasks:
            unit = next((u for u in self.units if u.task.upper() == task.upper()), None)
            if unit is None:
                continue  # not a motion task of this cell
            out.append(self.read_task(run, unit))
        return out

    def read_task(self, run: ProgramRun, unit: MechUnit) -> TaskProgram:
        """The program ``unit``'s task reads (``program_file``), decoded; a missing or
        malformed file is a ``ProgramFileError`` naming the task."""
        path = self.program_file(unit.task)
        try:
            data = run.controller.files.read(path)
        except RwsError:
            raise ProgramFileError("Motion program file not found", "nothing uploaded",
                                   path=path, task=unit.task) from None
        try:
            program = decode_program(data, path)
        except ProgramFileError as exc:
            exc.task = unit.task
            raise
        return TaskProgram(unit.task, unit, path, program)

    def __call__(self, run: ProgramRun) -> None:
        try:
            self._run(run)
        finally:
            self.shown()

    def shown(self) -> None:
        """After a run's motion: the camera shows the new state (``on_frame``) before
        the controller reads execution stopped."""
        if self.on_frame is not None:
            with self.cell_lock:
                self._publish()

    def _run(self, run: ProgramRun) -> None:
        programs = self._load(run)
        self.last_run = {tp.task: tp for tp in programs}
        if not programs:
            return
        plans = self._plans(run, programs)
        logging = _signal(run, "motion_program_log_motion") > 0
        offsets = {tp.task: tool_offset(tp.program.tool, self.pusher_length_mm)
                   for tp in programs}
        log = _Log(run, programs, logging, offsets)
        log.open()
        done = self._rounds(run, plans, log, programs[0].unit.arm)
        if done:
            log.close()
        else:
            log.write_file()  # stopped: what was logged, no "Closed" entry

    def _plans(self, run: ProgramRun, programs: Sequence[TaskProgram]
               ) -> dict[str, list[_Block | _Wait]]:
        """Every task's program as its arm's blocks and waits, from where the arm is."""
        with self.cell_lock:
            here = self._refresh()
        ratio = float(run.controller.speedratio)
        plans = {}
        for tp in programs:
            arm = tp.unit.arm
            ctx = _ArmContext(tp, tuple(here[arm]), self.arms.rest_joints(arm),  # type: ignore[arg-type]
                              self.cell.rest[arm], self.pusher_length_mm, ratio,
                              self.conf_j, partial(self._tip_of, arm),
                              v_max=self.velset(tp.task))
            plans[arm] = arm_plan(ctx)
            self.tools[arm] = tp.program.tool.tframe.trans
        return plans

    def _rounds(self, run: ProgramRun, plans: Mapping[str, list[_Block | _Wait]],
                log: _Log | None, lead: str) -> bool:
        """Run the arms' blocks together, round by round; False if stopped."""
        idx = dict.fromkeys(plans, 0)
        clock = 0.0
        while not run.stop_requested.is_set():
            blocks = {a: p[idx[a]] for a, p in plans.items()
                      if idx[a] < len(p) and isinstance(p[idx[a]], _Block)}
            if blocks:
                took = self._move(run, blocks, log, clock, lead)  # type: ignore[arg-type]
                if took is None:
                    return False
                clock += took
                for a in blocks:
                    idx[a] += 1
            waits = {a: p[idx[a]] for a, p in plans.items()
                     if idx[a] < len(p) and isinstance(p[idx[a]], _Wait)}
            if waits:
                t = max(w.t for w in waits.values())  # type: ignore[union-attr]
                _set_signal(run, "motion_program_current_cmd_num",
                            float(waits.get(lead, next(iter(waits.values()))).cmd_num))  # type: ignore[union-attr]
                if self.cell.realtime > 0 and run.stop_requested.wait(t / self.cell.realtime):
                    return False
                clock += t
                for a in waits:
                    idx[a] += 1
            if not blocks and not waits:
                return True
        return False

    def _move(self, run: ProgramRun, blocks: Mapping[str, _Block], log: _Log | None,
              t0: float, lead: str) -> float | None:
        """One ``cell.execute`` of every arm's block; its simulated time, None if stopped.
        The first planned stop, a world zone (:meth:`_path_zone_stop`) or the arms'
        supervision (:class:`ArmSupervisor`: reach, limits, configuration, singularity,
        contact), halts every arm at that moment and raises the controller's error."""
        programs = {a: b.waypoints for a, b in blocks.items()}
        with self.cell_lock:
            trajs = self._planned(programs, blocks)
            for arm, traj in trajs.items():
                if traj.segments:
                    self.arms.sync(arm, traj.segments[0].a)
            programs, trajs, stop_arm, tracks = within_speeds(  # type: ignore[assignment]
                programs, trajs, lambda p: self._planned(p, blocks), self.arms, self.tools)
            programs = {a: _along(wps, self.arms, a, tracks.get(a)) for a, wps in programs.items()}
            trajs = self._planned(programs, blocks)
            zone = self._path_zone_stop(tracks)
            stop_t = min((s.t for s in (zone, stop_arm) if s is not None), default=None)
            # a planned stop is found at the physics step it falls in, not the next sample
            every = self.frame_every_s if stop_t is None else TIME_STEP_S
            sampler = _Sampler(self, run, blocks, trajs, log, t0, lead, every, stop_t)
            try:
                took = self.cell.execute(programs, on_frame=sampler, frame_every_s=every)
            except _Halted:
                self._hold(trajs, sampler.last_t)
                self.arms.commit(tracks, sampler.last_t)
                self._refresh()
                return None
            except _ZoneHit:
                assert stop_t is not None
                self.cell.halt({a: traj.at(stop_t) for a, traj in trajs.items()})
                self.arms.commit(tracks, stop_t)
                tcps = self._refresh()
                if zone is not None and zone.t <= stop_t:
                    raise self._zone_error(zone, tcps) from None
                assert stop_arm is not None
                raise self._arm_error(stop_arm) from None
            self.arms.commit(tracks, math.inf)
            tcps = self._refresh()
        if log is not None:
            log.sample(t0 + took, {a: b.cmd_nums[-1] for a, b in blocks.items()}, tcps)
        return took

    def _planned(self, programs: Mapping[str, Sequence[Waypoint]],
                 blocks: Mapping[str, _Block]) -> dict[str, Trajectory]:
        try:
            return self.cell.plan(programs)
        except ValueError as exc:
            task = next(u.task for u in self.units if u.arm in blocks)
            raise program_failed("Motion refused by the twin cell", str(exc),
                                 task=task) from None

    def _path_zone_stop(self, tracks: Mapping[str, Any]) -> ZoneStop | None:
        """When the TCP of each arm's tool in use (:attr:`tools`) first reaches one of its
        world zones (:attr:`zones`) along the path the arm's joints really take (joint
        moves included): :meth:`ArmSupervisor.zone_entry`."""
        hit = self.arms.zone_entry(tracks, self.zones, self.tools)
        return None if hit is None else ZoneStop(hit[0], hit[1], hit[2], hit[3])

    def _arm_error(self, stop: ArmStop) -> RapidError:
        """The controller's error for a stop of the arms' supervision."""
        unit = next(u for u in self.units if u.arm == stop.arm)
        every = "Every motion task stopped." if stop.every_task else \
            f"Task {unit.task} stopped before the instruction."
        return ControllerStop(stop.code, stop.title, task=unit.task,
                          desc=f"Task {unit.task} ({unit.name}): {stop.detail}. {every}",
                          causes=_CAUSES[stop.reason], actions=_ACTIONS[stop.reason],
                          args=(unit.name, stop.detail))

    def _zone_error(self, zone: ZoneStop, tcps: Mapping[str, Sequence[float]]) -> RapidError:
        """The controller's error for a world-zone stop (see :meth:`_path_zone_stop`)."""
        raise NotImplementedError

    def _publish(self) -> None:
        """Show the cell's state on the camera (``on_frame``; the cell lock is held)."""
        if self.on_frame is not None:
            self.on_frame()

    def _hold(self, trajs: Mapping[str, Any], t: float) -> None:
        """After a stop: each pusher stays where its constraint was last put (the cell
        keeps it there); the cell's own record of the commanded TCP, from which its next
        program starts, is set to that point (``YumiTwinCell.hold``)."""
        for arm, traj in trajs.items():
            self.cell.hold(arm, traj.at(t))


def _along(waypoints: Sequence[Waypoint], arms: ArmSupervisor, arm: str, track: Any
           ) -> list[Waypoint]:
    """The waypoints with each joint move's ``path``: the pusher's tip where the arm's
    interpolated joints put it (``track``), so the cell's pusher goes where the arm
    takes it, not in a line between the ends."""
    if track is None:
        return list(waypoints)
    out, t0 = [], 0.0
    ends = list(track.ends) + [math.inf] * (len(waypoints) - len(track.ends))
    for wp, t1 in zip(waypoints, ends, strict=True):
        if wp.get("kind") in ("move_j", "rest") and t0 < t1 < math.inf:
            path = arms.tip_path(arm, track, t0, t1)
            if path:
                wp = {**wp, "path": [(t, list(p)) for t, p in path]}
        out.append(wp)
        t0 = t1
    return out


def _cumulative(durations: Any) -> list[float]:
    out, total = [], 0.0
    for d in durations:
        total += d
        out.append(total)
    return out


def _cmd_at(ends: Sequence[float], cmd_nums: Sequence[int], t: float) -> int:
    for end, n in zip(ends, cmd_nums, strict=True):
        if t < end:
            return n
    return cmd_nums[-1]
