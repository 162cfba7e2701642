"""Issue 43: a hostile program file moves no arm outside the controller's limits.

Every field a file can set has a limit our RAPID holds (robot/rapid/TestbedMotion.mod,
version 5; robot/README.md, "The limits a file cannot pass"): the speeds (the task
module's ``tb_v_tcp_max``, ``tb_v_ori_max``, ``tb_v_reax_max`` and ``TB_V_LEAX_MAX``),
the corner zones (z10's), the waits (``TB_WAIT_MAX``), the work object (wobj0's), no
number that is not finite; and, as before, the tool frame, the command count and the
floor. A file past one is refused before any motion with an 80001 entry whose lines name
the command and the field; a file within them runs, its TCP never faster than the cap
(VelSet's Max; a joint move's curve included).

Driven as an intruder or a PC with a bug would: files written by abb_motion_program_exec's
own ``MotionProgram``, uploaded with abb_robot_client's ``RWS.upload_file`` straight to the
task's file on the twin's RAM disk and started (``resetpp``, ``start``), the driver
bypassed. One plain test per limit pins each refusal by name (at the limit it runs, just
past it it is refused); a property test (hypothesis) generates files with random fields,
values at and past every limit, and checks each against an oracle written from the
module's reading order, and measures the TCP's speed on the cell's commanded trajectory
at every physics step.

On the modules before issue 43 (version 4) a MoveL at 1000 mm/s, a WaitTime 3600, a
200 mm corner zone and a shifted work object all ran: every refusal test here fails.
"""

from __future__ import annotations

import math
import random
import struct
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, replace
from typing import Any

import pytest
from abb_motion_program_exec import abb_motion_program_exec_client as mpe
from arm_plan import plan_nearest
from hypothesis import HealthCheck, find, given, settings
from hypothesis import strategies as st
from twin_rws import DOWN, OurTwin, our_twin, run, tool

from sim_twin.constants import TIME_STEP_S
from sim_twin.rws import testbed_rapid
from sim_twin.rws.testbed_file import (
    NOT_FINITE,
    SPEED_OVER,
    TOOL_DIFFERS,
    V_LEAX_MAX,
    V_ORI_MAX,
    V_REAX_MAX,
    V_TCP_MAX,
    WAIT_MAX,
    WAIT_OVER,
    WOBJ_REFUSED,
    ZONE_MAX,
    ZONE_OVER,
)
from sim_twin.rws.testbed_rapid import DONE, FAILED, WORLD_ZONE_CODE
from sim_twin.sew_angle import arm_angle
from sim_twin.yumi_arms import DEFAULT_TOOL_MM, ArmModel, abb_to_chain
from sim_twin.yumi_cell import Trajectory
from sim_twin.yumi_geometry import REST_JOINTS_DEG

TASK = "T_ROB_L"
PATH = "RAMDISK:/testbed_T_ROB_L.bin"
CONTROLLER_CODES = {50050, 50027, 50026, 50080, 50204, WORLD_ZONE_CODE}
"""The controller's own motion errors: a legal file to an unreachable target ends so."""
SPEEDS = ("v_tcp", "v_ori", "v_leax", "v_reax")
SPEED_CAP = {"v_tcp": ("tb_v_tcp_max", V_TCP_MAX), "v_ori": ("tb_v_ori_max", V_ORI_MAX),
             "v_leax": ("TB_V_LEAX_MAX", V_LEAX_MAX), "v_reax": ("tb_v_reax_max", V_REAX_MAX)}
ZONES = tuple(ZONE_MAX)
IDENTITY = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
NAN, INF = float("nan"), float("inf")


def f32(v: float) -> float:
    """What a file holds of ``v`` (every number is a float32)."""
    return float(struct.unpack("<f", struct.pack("<f", v))[0])


# --- a file, as data: what the generator draws and the oracle judges --------------------
@dataclass(frozen=True)
class Cmd:
    """One command: ``kind`` A (MoveAbsJ), J, L or W (WaitTime); ``at`` the target (mm, or
    the joints of a MoveAbsJ), ``speed`` (v_tcp, v_ori, v_leax, v_reax), ``zone`` (finep,
    then the six sizes), ``wait`` (s)."""

    kind: str
    at: tuple[float, ...] = ()
    speed: tuple[float, float, float, float] = (100.0, 100.0, 1000.0, 100.0)
    zone: tuple[bool, float, float, float, float, float, float] = (True, 0, 0, 0, 0, 0, 0)
    wait: float = 0.0
    angle: float | None = None
    """A robtarget's ``eax_a`` (ABB's arm angle, deg); None: the arm angle of the joints
    the driver plans for the target (:func:`arm_angles`)."""


@dataclass(frozen=True)
class File:
    cmds: tuple[Cmd, ...]
    tool_z: float = DEFAULT_TOOL_MM
    uframe: tuple[tuple[float, ...], tuple[float, ...]] = IDENTITY
    oframe: tuple[tuple[float, ...], tuple[float, ...]] = IDENTITY


def arm_angles(f: File) -> list[float]:
    """Each command's ``eax_a``: its own, else the arm angle of the joints the driver
    plans for its target (axis 7 at the push's 130, each from the joints before it: rest
    at first, a MoveAbsJ's after one; ``tests/sim_twin/arm_plan.py``), as a driver that
    sends its planned joints' arm angle writes it (docs/notes/rws.md, "What eax_a means
    on a YuMi"). A target the plan cannot reach (or not a number: the file is refused
    for it) gets the arm angle of the joints before it."""
    tool_z = f.tool_z if math.isfinite(f.tool_z) else DEFAULT_TOOL_MM
    current = abb_to_chain(REST_JOINTS_DEG["left"])
    out: list[float] = []
    for c in f.cmds:
        finite = all(math.isfinite(v) for v in c.at)
        if c.kind == "A" and finite:
            current = abb_to_chain(c.at)
        got = plan_nearest("left", c.at, current, tool_z) if c.kind in "JL" and finite \
            else None
        if got is not None:
            current = got[0]
        out.append(c.angle if c.angle is not None else
                   got[1] if got is not None else arm_angle(ArmModel("left").pose(current)))
    return out


def motion_program(f: File) -> Any:
    """The file as abb_motion_program_exec writes it."""
    wobj = mpe.wobjdata(False, True, "", mpe.pose(list(f.uframe[0]), list(f.uframe[1])),
                        mpe.pose(list(f.oframe[0]), list(f.oframe[1])))
    mp = mpe.MotionProgram(tool=tool(f.tool_z), wobj=wobj)
    for c, angle in zip(f.cmds, arm_angles(f), strict=True):
        speed, zone = mpe.speeddata(*c.speed), mpe.zonedata(*c.zone)
        if c.kind == "W":
            mp.WaitTime(c.wait)
        elif c.kind == "A":
            mp.MoveAbsJ(mpe.jointtarget(list(c.at[:6]), [c.at[6]] + [9e9] * 5), speed, zone)
        else:
            target = mpe.robtarget(list(c.at), DOWN, mpe.confdata(0, 0, 0, 4),
                                   [angle] + [9e9] * 5)
            (mp.MoveJ if c.kind == "J" else mp.MoveL)(target, speed, zone)
    return mp


NAME = {"A": "MoveAbsJ", "J": "MoveJ", "L": "MoveL", "W": "WaitTime"}


def oracle(f: File) -> tuple[str, str] | None:
    """The refusal our RAPID writes for ``f`` (its reason and the detail's start), from
    the module's reading order: the header (the tool frame, the work object), then each
    command as read: a record's numbers first (a NaN or inf is refused as it is read),
    then its checks, field by field. None: the file is within every limit."""
    if abs(f32(f.tool_z) - DEFAULT_TOOL_MM) > 1.0:
        return TOOL_DIFFERS, "file [[0,0,"
    for frame in (f.uframe, f.oframe):
        if any(not math.isfinite(v) for v in (*frame[0], *frame[1])):
            return NOT_FINITE, "wobjdata: not a finite number"
    for name, frame in (("uframe", f.uframe), ("oframe", f.oframe)):
        if tuple(map(f32, frame[0])) != IDENTITY[0] or tuple(map(f32, frame[1])) != IDENTITY[1]:
            return WOBJ_REFUSED, f"{name} [["
    for n, c in enumerate(f.cmds, start=1):
        if n > 64:
            return "Too many commands", "more than 64"
        what = f"{NAME[c.kind]} cmd_num {n}"
        if c.kind == "W":
            t = f32(c.wait)
            if not math.isfinite(t):
                return NOT_FINITE, f"{what}: not a finite number"
            if t < 0:
                return "Invalid WaitTime", f"{what}: "
            if t > WAIT_MAX:
                return WAIT_OVER, f"{what}: "
            continue
        target = "jointtarget" if c.kind == "A" else "robtarget"
        read = (*c.at, c.angle) if c.kind != "A" and c.angle is not None else c.at
        if any(not math.isfinite(f32(v)) for v in read):
            return NOT_FINITE, f"{what} {target}: not a finite number"
        if c.kind != "A" and f32(c.at[2]) < 0.0:
            return "Target below the table", f"{what}: z "
        speed = [f32(v) for v in c.speed]
        if any(not math.isfinite(v) for v in speed):
            return NOT_FINITE, f"{what} speeddata: not a finite number"
        for field, v in zip(SPEEDS, speed, strict=True):
            if v <= 0:
                return "Invalid speed", f"{what}: {field} = "
            if v > SPEED_CAP[field][1]:
                return SPEED_OVER, f"{what}: {field} "
        zone = [f32(v) for v in c.zone[1:]]
        if any(not math.isfinite(v) for v in zone):
            return NOT_FINITE, f"{what} zonedata: not a finite number"
        for field, v in zip(ZONES, zone, strict=True):
            if v < 0:
                return "Invalid zone", f"{what}: {field} = "
            if v > ZONE_MAX[field][1]:
                return ZONE_OVER, f"{what}: {field} "
    return None


# --- the twin, its speedometer -------------------------------------------------------------
class Speedometer:
    """The cell's commanded TCP speed (mm/s) per arm, at every physics step of every
    motion it executes: the largest seen since :meth:`reset` (``joint``: during joint
    moves, MoveJ and MoveAbsJ, alone)."""

    def __init__(self, t: OurTwin) -> None:
        self.cell, self.peak = t.cell, {"left": 0.0, "right": 0.0}
        self.joint = dict(self.peak)
        plain = t.cell.execute

        def execute(programs: Mapping[str, Sequence[Mapping[str, Any]]], **kw: Any) -> float:
            for arm, traj in self.cell.plan(programs).items():
                self.peak[arm] = max(self.peak[arm], fastest(traj))
                joint = [s for s, wp in zip(traj.segments, programs[arm], strict=True)
                         if wp.get("kind") == "move_j"]
                self.joint[arm] = max(self.joint[arm], fastest(Trajectory(joint)))
            return plain(programs, **kw)

        t.cell.execute = execute  # type: ignore[method-assign]

    def reset(self) -> None:
        self.peak = dict.fromkeys(self.peak, 0.0)
        self.joint = dict(self.peak)


def fastest(traj: Trajectory) -> float:
    """The largest distance per physics step (mm/s) of ``traj``'s commanded point (each
    segment from its own start)."""
    if len(traj.segments) != 1:
        return max((fastest(Trajectory([s])) for s in traj.segments), default=0.0)
    steps = math.ceil(traj.duration / TIME_STEP_S)
    prev, top = traj.at(0.0), 0.0
    for i in range(1, steps + 1):
        p = traj.at(i * TIME_STEP_S)
        top = max(top, math.dist(p, prev) / TIME_STEP_S)
        prev = p
    return top


class Rig:
    """A twin playing our RAPID (``our_twin``) with its :class:`Speedometer`; a fresh one
    when an arm cannot be brought home."""

    def __init__(self) -> None:
        self._open = ExitStack()
        self.seqno = 0
        self.fresh()

    def fresh(self) -> None:
        self._open.close()
        self._open = ExitStack()
        self.t = self._open.enter_context(our_twin())
        self.meter = Speedometer(self.t)

    def close(self) -> None:
        self._open.close()

    def state(self) -> tuple[Any, ...]:
        """The left arm's joints and both pushers: what a refused file must not change."""
        return (tuple(self.t.hook.arms.joints["left"]), self.t.tcps())

    def run(self, f: File | Any) -> list[Any]:
        """One start of the left task with ``f`` (a :class:`File` or a MotionProgram)."""
        self.seqno += 1
        self.meter.reset()
        mp = motion_program(f) if isinstance(f, File) else f
        return run(self.t.c, {TASK: mp}, seqno=self.seqno)

    def home(self) -> None:
        """Back to rest as the driver goes: straight up to 120 mm, then by joints (after
        a controller error left the arm anywhere); a fresh twin if that stops too."""
        x, y, _ = self.t.tcps()["left"]
        speed = (V_TCP_MAX, V_ORI_MAX, V_LEAX_MAX, V_REAX_MAX)
        got = self.run(File((Cmd("L", (x, y, 120.0), speed),
                             Cmd("A", tuple(REST_JOINTS_DEG["left"]), speed))))
        if [e.title for e in got] != [DONE]:
            self.fresh()


@pytest.fixture(scope="module")
def rig() -> Iterator[Rig]:
    r = Rig()
    yield r
    r.close()
    if TALLY:  # the property's figures (run with -s to see them)
        print(f"\nhostile files: {sum(TALLY.values())} examples, {dict(sorted(TALLY.items()))}"
              f"; the fastest TCP {PEAK['any']:.2f} mm/s, in a joint move {PEAK['joint']:.2f}"
              f" (cap {V_TCP_MAX:g})")


def refused(got: list[Any]) -> tuple[str, str]:
    """The one refusal a run wrote: (reason, detail)."""
    assert [(e.code, e.title, e.args[2]) for e in got] == [(80001, FAILED, PATH)], got
    return got[0].args[1], got[0].args[3]


# --- one plain test per limit -----------------------------------------------------------------
ABOVE = Cmd("J", (400.0, 200.0, 120.0), (V_TCP_MAX, V_ORI_MAX, V_LEAX_MAX, V_REAX_MAX))
"""A joint move to a tool-down point above the left box, at every cap."""
DOWN_TO = Cmd("L", (400.0, 200.0, 60.0), (100.0, 100.0, 1000.0, 100.0))


def push(**fields: Any) -> File:
    """ABOVE then a MoveL (cmd_num 2) down with ``fields`` changed (speed, zone, wait)."""
    return File((ABOVE, replace(DOWN_TO, **fields)))


def with_speed(field: str, v: float) -> File:
    s = dict(zip(SPEEDS, DOWN_TO.speed, strict=True))
    return push(speed=tuple({**s, field: v}.values()))


def with_zone(field: str, v: float) -> File:
    z = dict(zip(ZONES, (0.0,) * 6, strict=True))
    return push(zone=(False, *{**z, field: v}.values()))


LIMITS: dict[str, tuple[File, File, str, str]] = {
    **{f: (with_speed(f, cap), with_speed(f, cap + 0.01), SPEED_OVER,
           f"MoveL cmd_num 2: {f} {cap + 0.01:g} > {name} {cap:g}")
       for f, (name, cap) in SPEED_CAP.items()},
    **{f: (with_zone(f, cap), with_zone(f, cap + 0.01), ZONE_OVER,
           f"MoveL cmd_num 2: {f} {cap + 0.01:g} > {name} {cap:g}")
       for f, (name, cap) in ZONE_MAX.items()},
    "wait": (File((ABOVE, Cmd("W", wait=WAIT_MAX))), File((ABOVE, Cmd("W", wait=2.01))),
             WAIT_OVER, "WaitTime cmd_num 2: 2.01 s > TB_WAIT_MAX 2"),
    "v_tcp > 0": (with_speed("v_tcp", 20.0), with_speed("v_tcp", 0.0), "Invalid speed",
                  "MoveL cmd_num 2: v_tcp = 0"),
    "wait >= 0": (File((ABOVE, Cmd("W", wait=0.0))), File((ABOVE, Cmd("W", wait=-0.01))),
                  "Invalid WaitTime", "WaitTime cmd_num 2: -0.01 s"),
    "zone >= 0": (with_zone("pzone_tcp", 0.0), with_zone("pzone_tcp", -0.01), "Invalid zone",
                  "MoveL cmd_num 2: pzone_tcp = -0.01"),
    "wobj": (File((ABOVE,)), File((ABOVE,), uframe=((0.0, 0.0, -0.1), (1, 0, 0, 0))),
             WOBJ_REFUSED, "uframe [[0,0,-0.1],[1,0,0,0]]"),
    "finite": (with_speed("v_ori", 50.0), with_speed("v_ori", NAN), NOT_FINITE,
               "MoveL cmd_num 2 speeddata: not a finite number"),
}
"""limit -> (a file at it, one just past it, the reason, the detail)."""


@pytest.mark.parametrize("limit", list(LIMITS))
def test_each_limit_runs_at_it_and_is_refused_just_past_it(rig: Rig, limit: str) -> None:
    at, past, reason, detail = LIMITS[limit]
    ran = rig.run(at)
    assert [e.title for e in ran] == [DONE], ran
    before = rig.state()
    got = rig.run(past)
    assert refused(got) == (reason, detail)
    assert got[0].args[4].startswith("at byte ")
    assert rig.state() == before  # refused before any motion


def test_the_issues_files_are_refused_before_any_motion(rig: Rig) -> None:
    """What the issue measured as accepted (1000 mm/s, WaitTime 3600, a 200 mm zone, a
    shifted work object) and what was refused already (a target below the table, more
    than 64 commands): each refused, nothing moves."""
    before = rig.state()
    files = {
        SPEED_OVER: (with_speed("v_tcp", 1000.0),
                     "MoveL cmd_num 2: v_tcp 1000 > tb_v_tcp_max 150"),
        WAIT_OVER: (File((ABOVE, Cmd("W", wait=3600.0))),
                    "WaitTime cmd_num 2: 3600 s > TB_WAIT_MAX 2"),
        ZONE_OVER: (push(zone=tuple(mpe.z200)), "MoveL cmd_num 2: pzone_tcp 200 > TB_ZONE_MAX 10"),
        WOBJ_REFUSED: (File((ABOVE,), oframe=((0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0))),
                       "oframe [[0,0,0],[0,1,0,0]]"),
        "Target below the table": (File((ABOVE, replace(DOWN_TO, at=(400.0, 200.0, -5.0)))),
                                   "MoveL cmd_num 2: z -5 mm < 0 mm"),
        "Too many commands": (File((ABOVE, *[Cmd("W")] * 64)), "more than 64"),
    }
    for reason, (f, detail) in files.items():
        assert refused(rig.run(f)) == (reason, detail)
        assert rig.state() == before


def test_velset_holds_the_tcp_below_a_cap_the_lab_lowered(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A lab sets tb_v_tcp_max 80 (read over RWS as the modules declare it: what
    ``testbed check`` reads): 80.01 is refused; 80 runs, the cell's TCP never past 80
    mm/s, a MoveJ's curve included. And the second layer: with the file's speed check
    missed (the twin's reader told of no cap), a file at 150 still runs at most 80,
    VelSet's Max."""
    with our_twin(caps={"tb_v_tcp_max": 80.0}) as t:
        meter = Speedometer(t)
        assert t.c.get_rapid_variable("TestbedTask_L/tb_v_tcp_max", TASK) == "80"
        assert t.c.get_rapid_variable("TestbedTask_R/tb_v_ori_max", "T_ROB_R") == "100"
        fast = Cmd("J", (300.0, 100.0, 120.0), (80.0, 100.0, 1000.0, 100.0))
        there = replace(fast, kind="L", at=(450.0, 300.0, 90.0))
        over = File((replace(fast, speed=(80.01, 100.0, 1000.0, 100.0)),))
        assert refused(run(t.c, {TASK: motion_program(over)})) == (
            SPEED_OVER, "MoveJ cmd_num 1: v_tcp 80.01 > tb_v_tcp_max 80")
        got = run(t.c, {TASK: motion_program(File((fast, there)))}, seqno=2)
        assert [e.title for e in got] == [DONE]
        assert 60.0 < meter.peak["left"] <= 80.0 + 1e-6, meter.peak
        plain = testbed_rapid.read_program
        monkeypatch.setattr(testbed_rapid, "read_program", lambda data, held, limits: plain(
            data, held, replace(limits, v_tcp_max=math.inf)))
        meter.reset()
        at_150 = (150.0, 100.0, 1000.0, 100.0)
        got = run(t.c, {TASK: motion_program(File((replace(fast, speed=at_150),
                                                   replace(there, speed=at_150))))}, seqno=3)
        assert [e.title for e in got] == [DONE]
        assert 60.0 < meter.peak["left"] <= 80.0 + 1e-6, meter.peak


# --- the property ------------------------------------------------------------------------------
LEFT_BOX = ((200.0, 450.0), (80.0, 340.0))
"""Where the left arm's targets are drawn (inside its zone box, within reach)."""
HOSTILE: dict[str, list[float]] = {
    **{f: [SPEED_CAP[f][1] + 0.01, SPEED_CAP[f][1] * 10, 0.0, -1.0, NAN, INF] for f in SPEEDS},
    **{f: [cap + 0.01, cap * 20, -0.5, NAN, -INF] for f, (_, cap) in ZONE_MAX.items()},
    "wait": [WAIT_MAX + 0.01, 3600.0, -1.0, NAN, INF],
    "z": [-0.5, -50.0, NAN],
    "uframe": [0.1, -15.0, NAN],
    "oframe": [0.1, 30.0],
    "tool_z": [DEFAULT_TOOL_MM + 1.5, 0.0, 100.0],
    "count": [65.0],
    "eax_a": [NAN, INF],
}
"""Per field, values past its limit (just past, far past, at or below 0, NaN, inf). A
robtarget's arm angle has no limit a file can pass but a number's: any finite one is
legal, and one the arm cannot take is the controller's own error (:func:`legal_cmd`)."""


@st.composite
def legal_cmd(draw: st.DrawFn) -> Cmd:
    """A command within every limit (its values also AT the limits), its target on the
    table, above it or out of reach; a robtarget's arm angle mostly the driver's plan's,
    else any (130: axis 7's value, the old driver's; or drawn): one the arm cannot take
    there ends in the controller's own error, as a target out of reach does."""
    kind = draw(st.sampled_from("AJJLLLW"))
    speed = (draw(st.sampled_from([V_TCP_MAX, V_TCP_MAX, 100.0, 60.0])),
             draw(st.sampled_from([V_ORI_MAX, 60.0])), draw(st.sampled_from([V_LEAX_MAX, 5.0])),
             draw(st.sampled_from([V_REAX_MAX, 60.0])))
    zone = draw(st.sampled_from([tuple(mpe.fine), tuple(mpe.z10), tuple(mpe.z1),
                                 (False, *(cap for _, cap in ZONE_MAX.values()))]))
    if kind == "W":
        return Cmd("W", wait=draw(st.sampled_from([0.0, 0.0, 0.05, WAIT_MAX])))
    if kind == "A":
        rest = REST_JOINTS_DEG["left"]
        return Cmd("A", tuple(q + draw(st.floats(-8.0, 8.0)) for q in rest), speed, zone)
    (x0, x1), (y0, y1) = LEFT_BOX
    far = draw(st.integers(0, 9)) == 0
    heights = [100.0, 120.0] if kind == "J" else [0.0, 5.0, 40.0, 90.0, 110.0]
    at = (draw(st.floats(x0, x1)) + (400.0 if far else 0.0), draw(st.floats(y0, y1)),
          draw(st.sampled_from(heights)))
    angle = draw(st.sampled_from([None, None, None, 130.0, "drawn"]))
    if angle == "drawn":
        angle = draw(st.floats(-180.0, 180.0))
    return Cmd(kind, at, speed, zone, angle=angle)  # type: ignore[arg-type]


def _hostile(f: File, field: str, value: float, k: int) -> File:
    """``f`` with ``field`` set to ``value``: in the header, or in the ``k``-th (modulo)
    of its commands that have the field (a wait: its ``k``-th command becomes one)."""
    if field == "count":
        return replace(f, cmds=(*f.cmds, *[Cmd("W")] * 65))
    if field == "tool_z":
        return replace(f, tool_z=value)
    if field in ("uframe", "oframe"):
        frame = ((0.0, 0.0, value), (1.0, 0.0, 0.0, 0.0)) if field == "uframe" else \
            ((value, 0.0, 0.0), (math.cos(0.01), 0.0, 0.0, math.sin(0.01)))
        return replace(f, **{field: frame})
    cmds = list(f.cmds)
    if field == "wait":
        cmds[k % len(cmds)] = Cmd("W", wait=value)
        return replace(f, cmds=tuple(cmds))
    kinds = "JL" if field in ("z", "eax_a") else "AJL"
    have = [i for i, c in enumerate(cmds) if c.kind in kinds]
    if not have:
        cmds.append(Cmd("L", (300.0, 200.0, 120.0)))
        have = [len(cmds) - 1]
    i = have[k % len(have)]
    c = cmds[i]
    if field in SPEEDS:
        s = list(c.speed)
        s[SPEEDS.index(field)] = value
        cmds[i] = replace(c, speed=tuple(s))  # type: ignore[arg-type]
    elif field in ZONES:
        z = list(c.zone)
        z[1 + ZONES.index(field)] = value
        cmds[i] = replace(c, zone=tuple(z))  # type: ignore[arg-type]
    elif field == "eax_a":
        cmds[i] = replace(c, angle=value)
    else:
        cmds[i] = replace(c, at=(c.at[0], c.at[1], value))
    return replace(f, cmds=tuple(cmds))


@st.composite
def hostile_file(draw: st.DrawFn) -> File:
    """A legal file, and one time in two one or two fields set past a limit."""
    cmds = draw(st.lists(legal_cmd(), min_size=1, max_size=5))
    if draw(st.integers(0, 4)) > 0:  # mostly from above the box first, as the driver goes
        (x0, x1), (y0, y1) = LEFT_BOX
        cmds.insert(0, Cmd("J", (draw(st.floats(x0, x1)), draw(st.floats(y0, y1)), 120.0),
                           (V_TCP_MAX, V_ORI_MAX, V_LEAX_MAX, V_REAX_MAX)))
    f = File(tuple(cmds))
    # which fields, and how far past: uniform over every limit, seeded by the commands
    # drawn (hypothesis's own draws favour their first choices and repeat them)
    rng = random.Random(repr(cmds) + str(draw(st.integers(0, 9))))
    for _ in range(rng.choice([0, 0, 1, 2])):
        field = rng.choice(sorted(HOSTILE))
        f = _hostile(f, field, rng.choice(HOSTILE[field]), rng.randrange(6))
    return f


TALLY: Counter[str] = Counter()
"""The property's outcomes (printed when the module's twin closes)."""
PEAK = {"any": 0.0, "joint": 0.0}
"""The fastest TCP the property saw (mm/s): in any move, in a joint move."""


@pytest.mark.slow
@settings(max_examples=60, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(f=hostile_file())
def test_no_hostile_file_moves_an_arm_outside_the_limits_and_every_legal_one_runs(
        rig: Rig, f: File) -> None:
    """Each generated file: refused (the oracle's reason, a detail naming the command and
    field, nothing moved) when any field is past a limit; else it runs to its Done (or
    the controller's own motion error for a target out of reach or in a zone), its TCP at
    every physics step no faster than the file's fastest v_tcp and the cap, every wait
    it ran within TB_WAIT_MAX."""
    want = oracle(f)
    before = rig.state()
    got = rig.run(f)
    if want is not None:
        reason, detail = refused(got)
        assert (reason, detail[:len(want[1])]) == want, (f, got[0].args)
        assert rig.state() == before, f
        TALLY["refused: " + reason] += 1
        return
    codes = [e.code for e in got if e.msgtype == 3]
    assert not codes or (len(codes) == 1 and codes[0] in CONTROLLER_CODES), (f, got)
    moves = [c for c in f.cmds if c.kind != "W"]
    cap = min(V_TCP_MAX, max((f32(c.speed[0]) for c in moves), default=0.0))
    assert rig.meter.peak["left"] <= cap * (1 + 1e-9) + 1e-9, (f, rig.meter.peak)
    PEAK["any"] = max(PEAK["any"], rig.meter.peak["left"])
    PEAK["joint"] = max(PEAK["joint"], rig.meter.joint["left"])
    ran = rig.t.hook.last_run[TASK].program
    assert all(c.t <= WAIT_MAX for c in ran.commands if type(c).__name__ == "WaitTime")
    if codes:
        TALLY[f"ran: controller error {codes[0]}"] += 1
        rig.home()
    else:
        assert [e.title for e in got] == [DONE], got
        TALLY["ran: done"] += 1


def test_every_hostile_value_is_past_its_limit_by_the_oracle() -> None:
    """The property's hostile values (:data:`HOSTILE`) each refused by the oracle for its
    field, set on a legal file (no twin); and the generator draws legal files too."""
    base = File((ABOVE, DOWN_TO, Cmd("W")))
    kinds = {**dict.fromkeys(SPEEDS, (SPEED_OVER, "Invalid speed")),
             **dict.fromkeys(ZONES, (ZONE_OVER, "Invalid zone")),
             "wait": (WAIT_OVER, "Invalid WaitTime"), "z": ("Target below the table",),
             "uframe": (WOBJ_REFUSED,), "oframe": (WOBJ_REFUSED,), "tool_z": (TOOL_DIFFERS,),
             "count": ("Too many commands",), "eax_a": (NOT_FINITE,)}
    assert oracle(base) is None and set(kinds) == set(HOSTILE)
    for field, values in HOSTILE.items():
        for v in values:
            got = oracle(_hostile(base, field, v, 1))
            assert got is not None, (field, v)
            want = NOT_FINITE if not math.isfinite(v) else None
            assert got[0] == want or (want is None and got[0] in kinds[field]), (field, v, got)
    legal = find(hostile_file(), lambda f: oracle(f) is None and len(f.cmds) > 2,
                 settings=settings(database=None, derandomize=True, max_examples=200))
    assert oracle(legal) is None
