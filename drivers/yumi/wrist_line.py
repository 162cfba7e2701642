"""How the controller runs one straight line (MoveL) of the driver's, in the driver's model:
where it ends, the joints at every sample, and where it would stop.

Why a module of its own: the driver chooses each robtarget's arm angle by trying lines
(``drivers/yumi/line_plan.py``) and the layout check sweeps the lines so chosen
(``drivers/yumi/path_sweep.py``); both need the line as the controller runs it, with the
arm angle a robtarget's ``eax_a`` carries (ABB's, not axis 7's: docs/notes/rws.md, "What
eax_a means on a YuMi"; ``drivers/yumi/arm_angle.py``).

How a line runs (ConfL Off, SingArea Wrist: robot/rapid/TestbedMotion.mod; assumed, as
the twin does, ``sim_twin/rws/arm_supervision.py``): it ends in the solution of the
target's pose and arm angle nearest the start (:func:`line_end`); the tip runs along the
line, the arm angle turns evenly from the start's to the target's (the short way round)
and is held at every sample, the wrist's axes (4, 5, 6) turn evenly from the start's to
the end's (the tool's orientation exact at both ends, "allowed to differ somewhat"
between them, ABB's words for Wrist), and axes 1, 2, 7 and 3 hold the tip and the arm
angle (:func:`~drivers.yumi.arm_angle.hold_tip`; :func:`wrist_line`). It stops where the
arm cannot follow: out of reach, a joint past its limit, near a singularity (50050,
50027, 50026 on the controller).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import lru_cache
from typing import Final

import numpy as np
import numpy.typing as npt

from drivers.yumi.arm_angle import (
    SINGULAR_SIGMA,
    angle_step,
    arm_angle_deg,
    hold_tip,
    solve_with_arm_angle,
)
from drivers.yumi.arm_shapes import arm_capsules
from drivers.yumi.irb14000 import Arm
from drivers.yumi.irb14000_ik import ROT_WEIGHT_MM, _seeds, rotation_error
from drivers.yumi.reach import ArmTool

__all__ = ["ANGLE_STEP_DEG", "CENTRE_GAP_MM", "LINE_STEP_MM", "Chain", "far", "line_end",
           "natural_angle", "wrist_line"]

Mat = npt.NDArray[np.float64]
Chain = tuple[float, ...]
LINE_STEP_MM: Final = 10.0
ANGLE_STEP_DEG: Final = 3.0
"""A line is sampled at least every :data:`LINE_STEP_MM` of the tip's travel and every
this many degrees of its arm angle's turn and of each wrist axis's."""
WRIST: Final = (4, 5, 6)
"""Chain indices of axes 4, 5 and 6: turned evenly along a SingArea Wrist line."""
END_STEPS: Final = 6
NEAREST_SEEDS: Final = 3
NEAREST_ITERS: Final = 20
"""The search for a line's end where the nearest descents end past a limit
(:func:`line_end`): the start's wrist turned over and the first few of the inverse
kinematics' seeds, each a short descent (a layout check asks it of many arm angles)."""
NATURAL_DAMPING: Final = 20.0
"""The damping (mm) of :func:`natural_angle`'s least squares: steps stay small near a
singularity."""
CENTRE_GAP_MM: Final = 12.5
"""How far every link of a planned line keeps from the body's centre plane (half the
layout check's ``ARM_GAP_MM``, 25: two arms each so far from it are that far apart)."""


def _flange(tool: ArmTool, tcp_mm: Sequence[float], rot: Mat) -> Mat:
    """The flange's pose that puts the pusher's tip at ``tcp_mm`` turned ``rot``."""
    f = np.eye(4)
    f[:3, :3] = rot
    f[:3, 3] = np.asarray(tcp_mm, dtype=np.float64) - rot[:, 2] * tool.tool_z_mm
    return f


def line_end(tool: ArmTool, start: Chain, tcp_mm: Sequence[float], arm_angle: float
             ) -> Chain | None:
    """The solution of the target (the pusher's tip at ``tcp_mm``, the tool as ``tool``
    holds it, the arm angle ``arm_angle``) within the joint limits nearest ``start``,
    where a line from ``start`` ends (ConfL Off): the nearer (axes 1-5 and 7; axis 6 only
    turns the round pusher) of the pose and the arm angle carried from the start's to
    the target's in :data:`END_STEPS` steps, each solved from the last, and the target
    solved in one descent from the start; where both end past a limit, the nearest of
    the solutions found from the inverse kinematics' seeds
    (``drivers/yumi/irb14000_ik.py``) and the start's wrist turned over; None when there
    is none."""
    m = tool.model
    pose = m.pose(start)
    here = pose.tcp(tool.tool_z_mm)
    there = np.asarray(tcp_mm, dtype=np.float64)
    psi0 = arm_angle_deg(pose)
    swing = angle_step(psi0, arm_angle)
    r0 = pose.flange[:3, :3]
    q: Chain | None = start
    for k in range(1, END_STEPS + 1):
        f = k / END_STEPS
        target = _flange(tool, here + (there - here) * f, _between(r0, tool.rotation, f))
        got = solve_with_arm_angle(m, target, psi0 + swing * f, q)
        if got is None:
            q = None
            break
        q = got.chain_deg
    ends = [] if q is None or m.limit_excess(q) is not None else [q]
    flange = _flange(tool, there, tool.rotation)
    direct = solve_with_arm_angle(m, flange, arm_angle, start)
    if direct is not None:
        d = _turned_near(m, direct.chain_deg, start)
        ends += [d] if m.limit_excess(d) is None else []
    if ends:
        return min(ends, key=lambda e: far(e[:6], start[:6]))
    return _nearest_solution(tool, start, flange, arm_angle)


def natural_angle(tool: ArmTool, start: Chain, tcp_mm: Sequence[float]) -> float | None:
    """The arm angle the arm would end the line in if it moved least: the target's pose
    (the arm angle free) carried from the start's in :data:`END_STEPS` steps, each a
    damped least squares over all seven joints, whose steps are the smallest joint
    motion that moves the tool so (the elbow swung only as the pose needs); None when a
    step does not converge. One of the planner's first choices
    (``drivers/yumi/line_plan.py``)."""
    m = tool.model
    pose = m.pose(start)
    here = pose.tcp(tool.tool_z_mm)
    there = np.asarray(tcp_mm, dtype=np.float64)
    r0 = pose.flange[:3, :3]
    q = np.asarray(start, dtype=np.float64)
    for k in range(1, END_STEPS + 1):
        f = k / END_STEPS
        target = _flange(tool, here + (there - here) * f, _between(r0, tool.rotation, f))
        for _ in range(30):
            e = np.concatenate([target[:3, 3] - pose.flange[:3, 3],
                                rotation_error(pose.flange[:3, :3], target[:3, :3])
                                * ROT_WEIGHT_MM])
            if np.linalg.norm(e[:3]) < 0.05 and np.linalg.norm(e[3:]) < 0.1:
                break
            j = m.jacobian(pose, pose.flange[:3, 3])
            j[3:] *= ROT_WEIGHT_MM
            step = j.T @ np.linalg.solve(j @ j.T + NATURAL_DAMPING ** 2 * np.eye(6), e)
            q = q + np.degrees(np.clip(step, -0.2, 0.2))
            pose = m.pose(q)
        else:
            return None
    return arm_angle_deg(pose)


def _nearest_solution(tool: ArmTool, start: Chain, flange: Mat, arm_angle: float
                      ) -> Chain | None:
    m = tool.model
    s = list(start)
    seeds = [[s[0], s[1], s[2], s[3], s[4] + d4, -s[5], s[6] + 180.0] for d4 in (180.0, -180.0)]
    seeds += [list(v) for v in _seeds(m, s[2], None)[:NEAREST_SEEDS]]
    best: tuple[float, Chain] | None = None
    for seed in seeds:
        got = solve_with_arm_angle(m, flange, arm_angle, seed, iters=NEAREST_ITERS)
        if got is None:
            continue
        q = _turned_near(m, got.chain_deg, start)
        if m.limit_excess(q) is not None:
            continue
        apart = far(q, start)
        if best is None or apart < best[0]:
            best = (apart, q)
    return None if best is None else best[1]


def far(a: Chain, b: Chain) -> float:
    """The largest joint difference (deg) between two joint vectors."""
    return max(abs(x - y) for x, y in zip(a, b, strict=True))


def _turned_near(m: Arm, chain_deg: Sequence[float], near: Sequence[float]) -> Chain:
    """``chain_deg`` with each joint turned by whole turns, within its range, to the value
    nearest ``near``'s (the same pose)."""
    out = []
    for k, (q, s) in enumerate(zip(chain_deg, near, strict=True)):
        q = (q + 180.0) % 360.0 - 180.0
        turns = [q + t for t in (-360.0, 0.0, 360.0) if m.lower[k] <= q + t <= m.upper[k]]
        out.append(float(min(turns, key=lambda v: abs(v - s)) if turns else q))
    return tuple(out)


def _between(r0: Mat, r1: Mat, f: float) -> Mat:
    """The rotation ``f`` of the way from ``r0`` to ``r1`` (about one axis)."""
    v = rotation_error(r0, r1) * f
    a = float(np.linalg.norm(v))
    if a < 1e-12:
        return r0.copy()
    k = v / a
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return (np.eye(3) + math.sin(a) * kx + (1.0 - math.cos(a)) * (kx @ kx)) @ r0


def wrist_line(tool: ArmTool, start: Chain, end: Chain, arm_angle: float,
               room_deg: float = 0.0, sigma: float = SINGULAR_SIGMA
               ) -> tuple[list[Chain], str | None]:
    """A straight move from ``start`` to ``end`` (a solution of its target at the arm
    angle ``arm_angle``) as the controller runs it (the module's docstring), sampled at
    least every :data:`LINE_STEP_MM` mm and :data:`ANGLE_STEP_DEG` deg: the samples'
    joints, and where and why it stops (out of reach, a joint within ``room_deg`` of its
    limit, near a singularity: ``sigma``, a link out of the arm's own half of the cell:
    :data:`CENTRE_GAP_MM`), or None."""
    m = tool.model
    q0, q1 = np.asarray(start, dtype=np.float64), np.asarray(end, dtype=np.float64)
    here = m.pose(q0).tcp(tool.tool_z_mm)
    there = m.pose(q1).tcp(tool.tool_z_mm)
    angle0 = arm_angle_deg(m.pose(q0))
    swing = angle_step(angle0, arm_angle)
    wrist = list(WRIST)
    n = max(1, math.ceil(float(np.linalg.norm(there - here)) / LINE_STEP_MM),
            math.ceil(abs(swing) / ANGLE_STEP_DEG),
            math.ceil(float(np.max(np.abs(q1[wrist] - q0[wrist]))) / ANGLE_STEP_DEG))
    out: list[Chain] = []
    prev: Chain = tuple(float(v) for v in q0)
    for k in range(1, n + 1):
        f = k / n
        seed = np.asarray(prev)
        seed[wrist] = q0[wrist] + (q1[wrist] - q0[wrist]) * f
        tip = here + (there - here) * f
        got = _hold(tool, tuple(float(v) for v in tip), angle0 + swing * f,
                    tuple(float(v) for v in seed), prev, sigma)
        where = "(" + ", ".join(f"{v:.0f}" for v in tip) + ")"
        if not got[0]:
            return out, f"at {where}: {got[1]}"
        q = got[2]
        if room_deg > 0.0 and (close := _closest_limit(m, q, room_deg)) is not None:
            return out, f"at {where}: {close}"
        if (crossed := _across_centre(m, q, tool.tool_z_mm)) is not None:
            return out, f"at {where}: {crossed}"
        out.append(q)
        prev = q
    return out, None


def _across_centre(m: Arm, q: Chain, tool_z_mm: float) -> str | None:
    """Why the arm leaves its own half of the cell, or None: every link's and the
    gripper's capsule (``drivers/yumi/arm_shapes.py``) :data:`CENTRE_GAP_MM` clear of
    the body's centre plane (y = 0) on the arm's side. Two arms that each keep so are the
    layout check's ``ARM_GAP_MM`` (25) apart whatever each does; an elbow swung across
    meets the other arm (drivers/yumi/layout_check.py measures the sweeps apart)."""
    caps = arm_capsules(m.pose(q), tool_z_mm)
    side = 1.0 if m.side == "left" else -1.0
    low = np.minimum(caps.a[:, 1] * side, caps.b[:, 1] * side) - caps.r
    k = int(np.argmin(low))
    if low[k] >= CENTRE_GAP_MM:
        return None
    return (f"its {caps.names[k]} {CENTRE_GAP_MM - low[k]:.0f} mm into the other arm's half "
            f"(want {CENTRE_GAP_MM:g} mm from the body's centre plane)")


def _closest_limit(m: Arm, q: Chain, room_deg: float) -> str | None:
    axis, room = m.limit_room(q)
    return None if room >= room_deg else f"axis {axis} {room:.1f} deg from its limit"


@lru_cache(maxsize=20000)
def _hold(tool: ArmTool, tip: Chain, angle: float, seed: Chain, previous: Chain,
          sigma: float) -> tuple[bool, str, Chain]:
    """:func:`~drivers.yumi.arm_angle.hold_tip`, kept: a line's samples are a pure
    function of these, and the checks play the same lines again (``testbed calibrate``
    checks the whole robot after each arm; the layout check plans, then sweeps)."""
    got = hold_tip(tool.model, tip, tool.tool_z_mm, angle, seed, previous, sigma=sigma)
    return got.ok, got.reason, tuple(float(v) for v in got.pose.chain_deg)
