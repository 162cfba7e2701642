"""Can an arm reach its table box with the pusher down, and by how much: corners, margins.

Why a module between the kinematics and the checks: the driver (before a motion),
``testbed check`` and ``testbed calibrate`` (``drivers/yumi/layout_check.py``) and the
layout's tests ask the same two questions of a target: is it reachable with this tool at
the arm angle the calibration holds (:class:`ArmTool`), and how far further out could it
be (the reach margin, mm, measured horizontally away from the arm's shoulder, where a
reach runs out first). Whether the straight lines between targets run is the line planner's
(``drivers/yumi/line_plan.py``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Final

import numpy as np
import numpy.typing as npt

from drivers.yumi.irb14000 import Arm, Pose, arm
from drivers.yumi.irb14000_ik import DOWN, Solution, quat_matrix, solve_down

__all__ = ["ARM_ANGLE_DEG", "ARM_ANGLE_MAX_DEG", "REACH_MARGIN_MM", "ArmTool", "CornerReach",
           "box_corners", "corner_reaches", "default_arm_angle", "reach_margin", "side_of"]

Mat = npt.NDArray[np.float64]
REACH_MARGIN_MM: Final = 30.0
"""How much further out than a table box's corner the arm must still reach: calibration
error, a table box grown later, and the controller's own tolerance eat into it."""
MARGIN_SPAN_MM: Final = 150.0
"""The largest reach margin measured (a corner this far inside is simply "150+")."""


ARM_ANGLE_DEG: Final = {"left": -40.0, "right": 40.0}
"""ABB's arm angle (deg, the reference along axis 1: ``drivers/yumi/arm_angle.py``) each
arm's targets are solved at when a calibration names none: the elbow out and down with
the pusher over the table. Every target is solved at it, so the lines of every corner
program of the shipped boxes keep it, 3 deg or more from every joint limit, and the way
back retraces the way out (the line planner takes another angle where a line cannot run
at it: ``drivers/yumi/line_plan.py``; docs/notes/auto-day-one.md, "The redundancy")."""
ARM_ANGLE_MAX_DEG: Final = 90.0
"""A larger ``arm_angle_deg`` is an old calibration's axis-7 value (+-130), which a real
controller would read as an arm angle no push of the box can take: refused with the fix."""


def default_arm_angle(arm: str) -> float:
    """The arm angle a calibration of ``arm`` holds when it names none."""
    return ARM_ANGLE_DEG["right" if arm.startswith("r") else "left"]


def side_of(arm_name: str, task: str | None = None) -> str | None:
    """``left``/``right`` of an IRB 14000 arm, from its task (``T_ROB_L``) or name."""
    if task in ("T_ROB_L", "T_ROB_R"):
        return "left" if task.endswith("L") else "right"
    return arm_name if arm_name in ("left", "right") else None


@dataclass(frozen=True)
class ArmTool:
    """How an arm holds its pusher: the side, the tool's length (flange to tip,
    ``tool_z_mm``), ABB's arm angle every target is solved at (the calibration's
    ``arm_angle_deg``, the reference along axis 1: ``drivers/yumi/arm_angle.py``; -40
    left, +40 right shipped) and the tool's orientation (a robtarget's quaternion;
    default pointing down) its targets are sent with."""

    side: str
    tool_z_mm: float
    arm_angle_deg: float = 0.0
    tool_quat_wxyz: tuple[float, ...] = (0.0, 0.0, 1.0, 0.0)

    @property
    def model(self) -> Arm:
        return arm(self.side)

    @property
    def rotation(self) -> Mat:
        q = tuple(float(v) for v in self.tool_quat_wxyz)
        return DOWN if q == (0.0, 0.0, 1.0, 0.0) else quat_matrix(q)

    def solve(self, tcp_mm: Sequence[float], current: Sequence[float] | None = None
              ) -> Solution:
        """The arm's joints for ``tcp_mm``, from ``current`` (a numerical descent,
        milliseconds each). A solution is a pure function of the tool, the target and
        the seed, and a layout's checks ask the same ones again (``testbed calibrate``
        checks the whole robot after each arm, ``testbed check`` every robot of a
        lab), so the last few thousand are kept (their poses read-only)."""
        return _solve(self, tuple(float(v) for v in tcp_mm),
                      None if current is None else tuple(float(v) for v in current))


@lru_cache(maxsize=8192)
def _solve(tool: ArmTool, tcp_mm: tuple[float, ...], current: tuple[float, ...] | None
           ) -> Solution:
    seed_axis_7 = AXIS_7_SEED_DEG.get(tool.side, 0.0)
    first = solve_down(tool.model, tcp_mm, tool.tool_z_mm, seed_axis_7, tool.rotation,
                       current)
    sol = _held(tool, tcp_mm, current, first, tool.arm_angle_deg)
    for pose in (sol.pose, sol.near):
        if pose is not None:
            pose.frames.setflags(write=False)
    return sol


AXIS_7_SEED_DEG: Final = {"left": 130.0, "right": -130.0}
"""Axis 7 of the first descent's seeds (the pushes' elbow out, the wrist over the table):
a start for :func:`_held`, which then moves every joint to the held arm angle."""


def _held(tool: ArmTool, tcp_mm: tuple[float, ...], current: tuple[float, ...] | None,
          first: Solution, psi: float) -> Solution:
    """The joints of ``tcp_mm`` at the arm angle ``psi`` nearest ``current`` (else with the
    most room to the limits), seeded from the axis-7 descent's answer, ``current`` and the
    generic seeds. Why one arm angle held: the controller solves a robtarget at its
    ``eax_a``, so targets solved at one angle let the straight lines between them hold it
    and the way back retrace the way out (docs/notes/auto-day-one.md, "The redundancy"). None
    within the limits: the axis-7 descent's own reason when it found none either (out of
    reach is what a person can fix), else a ``limit`` naming the angle."""
    from drivers.yumi.arm_angle import SINGULAR_SIGMA, held_sigma, solve_with_arm_angle
    from drivers.yumi.irb14000_ik import _seeds

    m = tool.model
    f = np.eye(4)
    f[:3, :3] = tool.rotation
    f[:3, 3] = np.asarray(tcp_mm, dtype=np.float64) - tool.rotation[:, 2] * tool.tool_z_mm
    seeds = [list(p.chain_deg) for p in (first.pose, first.near) if p is not None]
    seeds += [list(current)] if current is not None else []
    seeds += [list(v) for v in _seeds(m, AXIS_7_SEED_DEG.get(tool.side, 0.0), None)[:8]]
    best: tuple[tuple[bool, float], Pose] | None = None
    singular: tuple[Pose, float] | None = None
    for seed in seeds:
        got = solve_with_arm_angle(m, f, psi, seed, iters=80)
        if got is None or m.limit_excess(got.chain_deg) is not None:
            continue
        sigma = held_sigma(m, got, tool.tool_z_mm)
        if sigma < HELD_SIGMA_FACTOR * SINGULAR_SIGMA:
            singular = singular if singular is not None and singular[1] > sigma else (got,
                                                                                      sigma)
            continue
        room = m.limit_room(got.chain_deg)[1]
        near = -max(abs(a - b) for a, b in zip(got.chain_deg, current, strict=True)) \
            if current is not None else room
        key = (room >= HELD_ROOM_DEG, near)
        if best is None or key > best[0]:
            best = (key, got)
    if best is not None:
        return Solution(best[1])
    if first.pose is None and first.kind == "reach":
        return first
    if singular is not None:
        return Solution(None, "singular", f"near a singularity at arm angle {psi:g} deg (the "
                        f"arm's smallest singular value {singular[1]:.4f}, under "
                        f"{HELD_SIGMA_FACTOR * SINGULAR_SIGMA:g})", near=singular[0])
    return Solution(None, "limit", f"no joints within the limits at arm angle {psi:g} deg")


HELD_SIGMA_FACTOR: Final = 2.0
"""A target's joints at least this many times the line planner's singularity bound from
a singularity (``drivers/yumi/arm_angle.py`` SINGULAR_SIGMA, the bound the planner's
first margin also asks): the lines from it have room to hold the tip and the angle."""
HELD_ROOM_DEG: Final = 3.0
"""A solution with this much room (deg) to every joint limit is preferred to a nearer
one with less (a line from it still has room to run)."""


def reach_margin(tool: ArmTool, tcp_mm: Sequence[float], pose: Pose,
                 span_mm: float = MARGIN_SPAN_MM) -> float:
    """How far (mm, to 2 mm) ``tcp_mm`` can move horizontally away from the shoulder and
    stay reachable, from its solution ``pose`` (bisection, each solve seeded by the last
    reachable one, as a linear move outward would go)."""
    p = np.asarray(tcp_mm, dtype=np.float64)
    d = p[:2] - tool.model.shoulder[:2]
    d /= max(float(np.linalg.norm(d)), 1e-9)
    lo, hi, seed = 0.0, span_mm, pose.chain_deg
    if (far := tool.solve([*(p[:2] + d * hi), p[2]], seed)).ok:
        return hi
    while hi - lo > 2.0:
        mid = (lo + hi) / 2
        far = tool.solve([*(p[:2] + d * mid), p[2]], seed)
        if far.ok:
            lo, seed = mid, far.pose.chain_deg if far.pose is not None else seed
        else:
            hi = mid
    return lo


def box_corners(box: Sequence[float], z_mm: float) -> list[tuple[float, float, float]]:
    x0, y0, x1, y1 = (float(v) for v in box)
    return [(x0, y0, z_mm), (x1, y0, z_mm), (x1, y1, z_mm), (x0, y1, z_mm)]


@dataclass(frozen=True)
class CornerReach:
    """One corner of a table box at one height: its solution and its reach margin."""

    tcp_mm: tuple[float, float, float]
    solution: Solution
    margin_mm: float | None
    """None when the corner itself is not reachable."""


def corner_reaches(tool: ArmTool, box: Sequence[float], heights: Sequence[float]
                   ) -> list[CornerReach]:
    """Every corner of ``box`` at every height in ``heights``, with its margin: solved as
    the arm gets there, each corner at the first height from the box's centre (a move
    inside the box) and at every later height from the same corner's previous solution
    (a straight move up or down keeps the arm's configuration)."""
    out: list[CornerReach] = []
    cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
    centre = tool.solve((cx, cy, heights[0]))
    seeds: list[Sequence[float] | None] = [
        centre.pose.chain_deg if centre.pose is not None else None] * 4
    for z in heights:
        for k, c in enumerate(box_corners(box, z)):
            sol = tool.solve(c, seeds[k])
            margin = None if sol.pose is None else reach_margin(tool, c, sol.pose)
            if sol.pose is not None:
                seeds[k] = sol.pose.chain_deg
            out.append(CornerReach(c, sol, margin))
    return out
