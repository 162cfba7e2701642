"""A YuMi program played through the arm's model: where the pusher's tip and the links go.

Why: the world zones (our RAPID's ``tb_zones``) stop the arm when the tip of the tool in
use goes below ``tb_zone_z`` outside the zone box, or below ``tb_floor_z``, anywhere on
its path, joint moves included. A joint move's path is not programmed: the controller
interpolates every joint linearly, all together, so the tip swings along a curve. This
module plays a list of the driver's waypoints (``drivers/yumi/yumi_controller.Waypoint``)
from a joint vector the way the controller would (a joint move to a joint target, rest
or the gate: the joints interpolated between two known joint vectors, exactly as the
controller does; a straight move: the tip along the line and the arm angle the
robtarget carries turned evenly to it and held, as planned and sent:
``drivers/yumi/line_plan.py``) and measures every sample against the zones. The
layout check (``drivers/yumi/layout_check.py``) plays the paths the driver commands for
every corner of the table box; the tests play the driver's own recorded programs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from drivers.yumi.arm_shapes import arm_capsules
from drivers.yumi.irb14000 import Pose
from drivers.yumi.line_plan import planned_targets
from drivers.yumi.reach import ArmTool
from drivers.yumi.yumi_controller import Waypoint

__all__ = ["Sample", "Worst", "ZoneSpec", "joint_move", "play", "worst", "zone_clearance"]

JOINT_STEP_DEG = 1.0


@dataclass(frozen=True)
class ZoneSpec:
    """The zones of one task: the box (x0, y0, x1, y1) the tip may go below ``zone_z``
    in, and the floor (None: not known)."""

    box: tuple[float, float, float, float] | None
    zone_z: float | None
    floor_z: float | None = None


@dataclass(frozen=True)
class Sample:
    """One point of a played path: the pose, its tip and which leg it is on."""

    pose: Pose
    tip: tuple[float, float, float]
    leg: str


@dataclass(frozen=True)
class Worst:
    """The smallest clearance (mm; negative: inside a zone by that much) over a path,
    where (``point``), of what (``part``: the pusher's tip or a link) and on which leg."""

    clearance: float
    point: tuple[float, float, float]
    part: str
    leg: str


def zone_clearance(p: Sequence[float], zones: ZoneSpec) -> float:
    """How far ``p`` is from the zones (negative: how deep inside): the region below
    ``zone_z`` outside the box, and below the floor (which counts only once crossed: a
    push runs a few mm above the table by design)."""
    x, y, z = (float(v) for v in p)
    out = math.inf
    if zones.floor_z is not None and z < zones.floor_z:
        out = z - zones.floor_z
    if zones.zone_z is None or zones.box is None:
        return out
    x0, y0, x1, y1 = zones.box
    inside = x0 <= x <= x1 and y0 <= y <= y1
    if not inside:  # outside the box: only height keeps it out of the zone
        dx = max(x0 - x, 0.0, x - x1)
        dy = max(y0 - y, 0.0, y - y1)
        depth = min(zones.zone_z - z, math.hypot(dx, dy)) if z < zones.zone_z else None
        return min(out, z - zones.zone_z if depth is None else -depth)
    edge = min(x - x0, x1 - x, y - y0, y1 - y)
    return min(out, edge if z < zones.zone_z else math.hypot(edge, z - zones.zone_z))


def _tip(pose: Pose, tool: ArmTool) -> tuple[float, float, float]:
    t = pose.tcp(tool.tool_z_mm)
    return (float(t[0]), float(t[1]), float(t[2]))


def joint_move(tool: ArmTool, a: Sequence[float], b: Sequence[float], leg: str
               ) -> list[Sample]:
    """The samples of a joint move from chain joints ``a`` to ``b`` (every joint
    linearly, all together), ``a`` left out: at least one every :data:`JOINT_STEP_DEG`."""
    qa, qb = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    n = max(2, math.ceil(float(np.max(np.abs(qb - qa))) / JOINT_STEP_DEG))
    poses = [tool.model.pose(qa + (qb - qa) * k / n) for k in range(1, n + 1)]
    return [Sample(p, _tip(p, tool), leg) for p in poses]


def play(tool: ArmTool, start_chain: Sequence[float], rest_abb: Sequence[float] | None,
         waypoints: Sequence[Waypoint], label: str = "") -> tuple[list[Sample], str | None]:
    """The samples of ``waypoints`` played from ``start_chain`` (chain order), and the
    reason it stopped early (a target the model cannot reach, a line the arm cannot run
    holding its arm angle) or None. Each waypoint is planned as the driver sends it
    (:func:`drivers.yumi.line_plan.planned_targets`: a robtarget's arm angle in
    ``eax_a``, the joints it ends in); a joint move runs to the planned joints, a
    straight move as the controller runs it (:func:`drivers.yumi.wrist_line.wrist_line`:
    the tip on the line, the arm angle turned evenly and held)."""
    plan, why = planned_targets(tool, start_chain, rest_abb, waypoints)
    q = list(start_chain)
    out: list[Sample] = []
    for w, target in zip(waypoints, plan, strict=False):
        if w.kind in ("rest", "abs_j"):
            where = ("rest" if w.kind == "rest" else "the gate joints" if not out
                     else "the gate joints (the correction)")
            out += joint_move(tool, q, target.chain_deg, f"{label}joint move to {where}")
        else:
            assert w.xyz_mm is not None
            xyz = tuple(float(v) for v in w.xyz_mm)
            leg = f"{label}{'joint' if w.kind == 'move_j' else 'straight'} move to {_pt(xyz)}"
            if w.kind == "move_j" or not target.line:
                out += joint_move(tool, q, target.chain_deg, leg)
            else:
                poses = [tool.model.pose(c) for c in target.line]
                out += [Sample(p, _tip(p, tool), leg) for p in poses]
        q = list(target.chain_deg)
    if why is not None:
        return out, why
    return out, None


def worst(samples: Sequence[Sample], tool: ArmTool, zones: ZoneSpec) -> Worst | None:
    """The smallest clearance to the zones over ``samples``: the pusher's tip (the
    point the zones supervise) and every link's lowest surface (a capsule's ends less
    its radius; the pusher's own capsule is the tip's)."""
    best: Worst | None = None
    for s in samples:
        c = zone_clearance(s.tip, zones)
        if best is None or c < best.clearance:
            best = Worst(c, s.tip, "pusher's tip", s.leg)
        caps = arm_capsules(s.pose, tool.tool_z_mm).without_tool()
        for a, b, r, name in zip(caps.a, caps.b, caps.r, caps.names, strict=True):
            for p in (a, b):
                low = (float(p[0]), float(p[1]), float(p[2]) - float(r))
                c = zone_clearance(low, zones)
                if c < best.clearance:
                    best = Worst(c, low, name, s.leg)
    return best


def _pt(p: Sequence[float]) -> str:
    return "(" + ", ".join(f"{v:.0f}" for v in p) + ")"
