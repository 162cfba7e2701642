"""The arm angle of each robtarget the driver sends, chosen so that the controller can run
the straight line to it: the plan the driver sends and the layout check sweeps.

Why a plan and not one number: a robtarget's ``eax_a`` on a YuMi is ABB's arm angle
(``drivers/yumi/arm_angle.py``), and along a MoveL the controller turns it evenly from the
arm's to the target's and holds it at every point, axis 7 moving as it must
(docs/notes/rws.md, "What eax_a means on a YuMi"). With the pusher down over the table
that is a narrow road. Since issue 43 the driver's inverse kinematics solves every target
at the calibration's held arm angle (``drivers/yumi/reach.py``: -40 left, +40 right), so
the first choices below are that angle and a push's lines keep it (in the model every
corner program of the shipped boxes does; a referee's 48 random programs did too). When
a line cannot run at it (another layout, another arm angle in the calibration), each
line's arm angle is chosen where the line runs (:func:`planned_targets`), tried in this
order: the arm angle the program holds there before or goes on from (a way back retraces
the way out, and ends in the gate joints it left); the one the arm would end in moving
least; the one of the joints the inverse kinematics picks there and the start's turned
by :data:`TURNS_DEG`, the least turn first. Those whose
line the model runs (``drivers/yumi/wrist_line.py``) with room to every limit and from a
singularity (:data:`MARGINS`), each arm in its own half of the cell, are taken, those
whose arm joints turn more than a short line needs last; a line whose
choice leaves the next one none is tried again with the next choice (a depth-first
search, bounded by :data:`PLAN_BUDGET`). Whatever angle a line takes, its robtarget
carries it, and the layout check sweeps the plan. A program with no plan is refused before
anything moves (the controller would stop the line half-way), and the layout check
FAULTs the path.

How a line runs, and where it stops: ``drivers/yumi/wrist_line.py``.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Final

import numpy as np
import numpy.typing as npt

from drivers.yumi.arm_angle import SINGULAR_SIGMA, angle_step, arm_angle_deg
from drivers.yumi.reach import ArmTool
from drivers.yumi.wrist_line import Chain, far, line_end, natural_angle, wrist_line
from drivers.yumi.yumi_controller import Waypoint

__all__ = ["PLAN_ROOM_DEG", "TURNS_DEG", "PlannedTarget", "planned_targets"]

Mat = npt.NDArray[np.float64]
PLAN_ROOM_DEG: Final = 3.0
"""How far from every joint limit a planned line stays (the layout check's sweep and the
controller allow it to the limit): the controller's line and the model's differ by the
model's error and by the end each finds."""
TURNS_DEG: Final = tuple(float(d) for d in range(-90, 91, 10))
"""The arm angles tried after the inverse kinematics' own: the start's turned by these."""
TRAVEL_MIN_DEG: Final = 45.0
TRAVEL_DEG_PER_MM: Final = 0.5
"""A line whose axes 1, 2, 7 or 3 turn more than the larger of these (per mm of the
tip's travel) is taken only when no arm angle gives one that turns less (:func:`_legs`):
from the shipped gate to (196, 256) at travel height, 115 mm away, the first arm angle
that runs swings axis 1 by 147 deg, another by 68."""
MARGINS: Final = ((PLAN_ROOM_DEG, 2.0 * SINGULAR_SIGMA),)
"""The margins a line is planned with, the first where one runs: (deg to every joint
limit, the smallest singular value). One, with room: the twin's line and the model's
differ (the twin turns the round pusher freely about its axis at a line's end, the real
controller's joints are a few tenths off the model's), and a plan with half this room
stopped the rehearsal's calibration on the twin with 50027, axis 1 1.3 deg past its
limit."""
HOPELESS: Final = ("cannot be held", "past its limit", "other arm's half")
"""Why a try fails whatever the margin (the room to the limits, the singularity's):
:func:`_legs` does not try it again at the next margin."""
HELD_MM: Final = 1.0
"""A target this close to a pose planned before in the program is the same point (its
arm angle there is tried: :func:`_tries`)."""


@dataclass(frozen=True)
class PlannedTarget:
    """What the driver plans for one waypoint: the joints it ends in and, for a
    robtarget, the arm angle sent in ``eax_a`` (None for a joint target, whose
    ``eax_a`` is axis 7's value) and the line's samples there (a straight move's, chain
    joints; empty for a joint move)."""

    chain_deg: Chain
    arm_angle_deg: float | None
    line: tuple[Chain, ...] = ()


Leg = tuple[float, Chain, tuple[Chain, ...]]
"""A planned line: its arm angle, the joints it ends in, its samples."""


@lru_cache(maxsize=8192)
def _line_end(tool: ArmTool, start: Chain, tcp_mm: Chain, psi: float) -> Chain | None:
    """:func:`line_end`, kept (the same end is asked for at each margin)."""
    return line_end(tool, start, tcp_mm, psi)


@lru_cache(maxsize=8192)
def _option(tool: ArmTool, start: Chain, tcp_mm: Chain, psi: float, before: Chain | None,
            room: float, sigma: float) -> Leg | str:
    """The line to ``tcp_mm`` from ``start`` at the arm angle ``psi`` (ending in
    ``before``, the joints held there before, when they are the nearest end), if the
    model runs it with ``room`` deg to every limit and ``sigma`` from a singularity;
    else why not."""
    end = _line_end(tool, start, tcp_mm, psi)
    if before is not None and (end is None or far(before, start) < far(end, start)):
        end = before
    if end is None:
        return f"the arm angle {psi:.0f} deg cannot be held at the target"
    if (over := tool.model.limit_room(end))[1] < room:
        return f"the target at arm angle {psi:.0f} deg has axis {over[0]} at its limit"
    samples, err = wrist_line(tool, start, end, psi, room, sigma)
    if err is not None:
        return f"the line at arm angle {psi:.0f} deg stops {err}"
    return psi, samples[-1] if samples else end, tuple(samples)


@lru_cache(maxsize=4096)
def _tries(tool: ArmTool, start: Chain, tcp_mm: Chain, ik_angle: float,
           held: tuple[tuple[float, Chain], ...]) -> tuple[tuple[float, Chain | None], ...]:
    """The arm angles a line to ``tcp_mm`` from ``start`` is tried at, in order: those
    ``held`` there (the joint target the program goes to next from there, and the poses
    planned there before in the program), each with those joints as its end (a way back
    retraces the way out, and ends in the joints it left); the one the arm would end in
    moving least (:func:`natural_angle`); the inverse kinematics' ``ik_angle`` and the
    start's turned by :data:`TURNS_DEG`, the least turn first (the elbow swung least; on
    a tie the inverse kinematics')."""
    psi0 = arm_angle_deg(tool.model.pose(start))
    turns = sorted([ik_angle, *(psi0 + t for t in TURNS_DEG)],
                   key=lambda a: abs(angle_step(psi0, a)))
    natural = natural_angle(tool, start, tcp_mm)
    out: list[tuple[float, Chain | None]] = []
    for angle, before in (*held, (psi0, None), *([] if natural is None else [(natural, None)]),
                          *((a, None) for a in turns)):
        psi = round((angle + 180.0) % 360.0 - 180.0, 6)
        if before is None and any(b is None and abs(angle_step(psi, t)) < 1.0
                                  for t, b in out):
            continue
        out.append((psi, before))
    return tuple(out)


def _legs(tool: ArmTool, start: Chain, tcp_mm: Chain, ik_angle: float,
          held: tuple[tuple[float, Chain], ...], why: list[str], budget: list[int]
          ) -> Iterator[Leg]:
    """The lines to ``tcp_mm`` from ``start`` the model runs, at each of :data:`MARGINS`
    in turn; at each margin, in the order of :func:`_tries` those whose
    axes 1, 2, 7 and 3 turn no more than :func:`_travel_allowed` along the line, then
    the others, least turn first (an arm angle that makes the elbow swing round for a
    short line is the last choice). The first reason a try failed (at the last margin)
    is put in ``why``; each try spends one of ``budget[0]``."""
    tries = _tries(tool, start, tcp_mm, ik_angle, held)
    allowed = _travel_allowed(tool, start, tcp_mm)
    given: set[float] = set()
    hopeless: set[int] = set()  # tries that fail at the limits too: not tried again there
    for room, sigma in MARGINS:
        later: list[tuple[float, Leg]] = []
        for k, (psi, before) in enumerate(tries):
            if k in hopeless:
                continue
            if budget[0] <= 0:
                why.append("the search gave up (too many arm angles tried)")
                return
            budget[0] -= 1
            got = _option(tool, start, tcp_mm, psi, before, room, sigma)
            if isinstance(got, str):
                if any(w in got for w in HOPELESS):
                    hopeless.add(k)
                    if not why:
                        why.append(got)
                elif room == MARGINS[-1][0] and not why:
                    why.append(got)
                continue
            if got[0] in given:
                continue
            given.add(got[0])
            turned = _turned(start, got[2])
            if turned <= allowed:
                yield got
            else:
                later.append((turned, got))
        for _, got in sorted(later, key=lambda t: t[0]):
            yield got


def _turned(start: Chain, samples: Sequence[Chain]) -> float:
    """The most any of axes 1, 2, 7 and 3 turns along a line's samples (deg)."""
    q = np.asarray([start, *samples], dtype=np.float64)[:, :4]
    return float(np.abs(np.diff(q, axis=0)).sum(axis=0).max())


def _travel_allowed(tool: ArmTool, start: Chain, tcp_mm: Chain) -> float:
    """How far (deg) an arm joint may turn along a line before another arm angle is
    looked for first: :data:`TRAVEL_MIN_DEG`, or :data:`TRAVEL_DEG_PER_MM` of the tip's
    travel on a long line."""
    length = float(np.linalg.norm(np.asarray(tcp_mm) - tool.model.pose(start).tcp(
        tool.tool_z_mm)))
    return max(TRAVEL_MIN_DEG, TRAVEL_DEG_PER_MM * length)


def planned_targets(tool: ArmTool, start_chain: Sequence[float] | None,
                    rest_abb: Sequence[float] | None, waypoints: Sequence[Waypoint]
                    ) -> tuple[list[PlannedTarget], str | None]:
    """Each waypoint's plan from ``start_chain`` (the arm's joints, chain order; None: the
    program starts with a joint target): a joint target's joints; a robtarget's arm
    angle, end joints and line (a straight move: the first of :func:`_legs` from which
    the rest of the program can be planned too, up to :data:`OPTIONS_PER_LEG` tried; a
    joint move, MoveJ: the inverse kinematics' joints and their arm angle, the controller
    choosing the configuration, ConfJ Off). When there is none: the plans of the
    waypoints before the one that stopped the furthest try, and why (the model's words),
    else None. The driver's program (``drivers/yumi/rws_controller.py``) and the layout
    check's sweep (``drivers/yumi/path_sweep.py``) both plan here: the arm angle swept is
    the one sent."""
    start = None if start_chain is None else tuple(float(v) for v in start_chain)
    held: tuple[tuple[Mat, float, Chain], ...] = ()
    if start is not None:
        held = (_held(tool, start),)
    furthest: list[tuple[list[PlannedTarget], str]] = []
    got = _plan(tool, tuple(waypoints), rest_abb, 0, start, held, [], furthest,
                [PLAN_BUDGET])
    if got is not None:
        return got, None
    out, why = max(furthest, key=lambda f: len(f[0]))
    return out, why


OPTIONS_PER_LEG: Final = 24
"""How many of a line's runnable arm angles are tried before the plan of the program
is given up (each may leave the next line none: over the shipped right box, from the
gate, the first nine arm angles that reach (460, -268) at travel height put axis 1
within 10 deg of its limit, and no line down from them runs)."""
PLAN_BUDGET: Final = 300
"""How many lines one program's plan may try in all: a bound on the search's time (a try
costs up to some 40 ms; over the tests' box a push's plan takes 0.2 to 1 s, one near the
inner near corner that has none up to 13 s before the program is refused)."""


def _next_joints(tool: ArmTool, waypoints: tuple[Waypoint, ...], k: int,
                 rest_abb: Sequence[float] | None) -> tuple[tuple[Mat, float, Chain], ...]:
    """The joint target waypoint ``k`` goes to, if it is one (the gate joints after the
    line back to the gate's point): a line that ends in them leaves the correction
    nothing to turn."""
    if k >= len(waypoints) or waypoints[k].kind not in ("rest", "abs_j"):
        return ()
    joints = rest_abb if waypoints[k].kind == "rest" else waypoints[k].joints_deg
    if joints is None or len(joints) != 7:
        return ()
    return (_held(tool, tuple(tool.model.pose_abb(joints).chain_deg)),)


def _held(tool: ArmTool, q: Chain) -> tuple[Mat, float, Chain]:
    pose = tool.model.pose(q)
    return pose.tcp(tool.tool_z_mm), arm_angle_deg(pose), q


def _plan(tool: ArmTool, waypoints: tuple[Waypoint, ...], rest_abb: Sequence[float] | None,
          k: int, here: Chain | None, held: tuple[tuple[Mat, float, Chain], ...],
          out: list[PlannedTarget], furthest: list[tuple[list[PlannedTarget], str]],
          budget: list[int]) -> list[PlannedTarget] | None:
    """:func:`planned_targets` from waypoint ``k`` on (a depth-first search over each
    line's arm angles); a failure is put in ``furthest``."""
    m = tool.model
    if k == len(waypoints):
        return out
    w = waypoints[k]
    if w.kind in ("rest", "abs_j"):
        joints = rest_abb if w.kind == "rest" else w.joints_deg
        if joints is None or len(joints) != 7:
            furthest.append((out, f"no {'rest' if w.kind == 'rest' else 'target'} joints"))
            return None
        q = tuple(m.pose_abb(joints).chain_deg)
        return _plan(tool, waypoints, rest_abb, k + 1, q, (*held, _held(tool, q)),
                     [*out, PlannedTarget(q, None)], furthest, budget)
    if w.xyz_mm is None:
        furthest.append((out, f"a {w.kind} waypoint without a position"))
        return None
    xyz = tuple(float(v) for v in w.xyz_mm)
    where = "(" + ", ".join(f"{v:.0f}" for v in xyz) + ")"
    sol = tool.solve(xyz, here)
    pose = sol.pose if sol.pose is not None else sol.near
    if pose is None:
        furthest.append((out, f"{where}: {sol.reason}"))
        return None
    if w.kind == "move_j" or here is None:
        q = tuple(pose.chain_deg) if here is None else _nearest_flip(tool, pose.chain_deg, here)
        return _plan(tool, waypoints, rest_abb, k + 1, q, (*held, _held(tool, q)),
                     [*out, PlannedTarget(q, arm_angle_deg(pose))], furthest, budget)
    after = _next_joints(tool, waypoints, k + 1, rest_abb)
    before = tuple((round(a, 6), q) for tip, a, q in (*after, *reversed(held))
                   if float(np.linalg.norm(tip - np.asarray(xyz))) < HELD_MM)
    why: list[str] = []
    for n, (psi, end, samples) in enumerate(_legs(tool, here, xyz,
                                                  round(arm_angle_deg(pose), 6), before, why,
                                                  budget)):
        if n >= OPTIONS_PER_LEG:
            break
        done = _plan(tool, waypoints, rest_abb, k + 1, end,
                     (*held, (np.asarray(xyz), psi, end)),
                     [*out, PlannedTarget(end, psi, samples)], furthest, budget)
        if done is not None:
            return done
    else:
        furthest.append((out, f"no straight line to {where} the arm can run: "
                              f"{why[0] if why else 'no arm angle tried'}"))
    return None


def _nearest_flip(tool: ArmTool, q: Sequence[float], here: Chain) -> Chain:
    """Of ``q`` and its wrist turned over (axis 4 half a turn, axis 5 negated, axis 6 half
    a turn: the same flange pose and arm angle), within the limits, the one nearest
    ``here`` (the largest joint turn): where a MoveJ to the robtarget ends, ConfJ Off
    ("the closest configuration"), as the twin takes it (``sim_twin/rws/arm_supervision.py``).
    Over the table the pusher points down near the wrist's singularity (axis 5 near 0),
    where the two are a few degrees of axis 5 apart and the inverse kinematics' descent
    may end in either."""
    m = tool.model
    base = tuple(float(v) for v in q)
    out = [base]
    for d4 in (180.0, -180.0):
        for d6 in (180.0, -180.0):
            f = (*base[:4], base[4] + d4, -base[5], base[6] + d6)
            if m.limit_excess(f) is None:
                out.append(f)
    return min(out, key=lambda c: far(c, here))
