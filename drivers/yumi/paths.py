"""The paths every YuMi program takes between the rest pose and the table: one place.

Why a module of its own: the driver (``drivers/yumi/backend.py``) commands these paths and
``testbed check`` (``drivers/yumi/layout_check.py``) sweeps the pusher's tip and the links
along the same ones against the world zones, so the two can never disagree about what the
arm does. The zones (our RAPID's ``tb_zones``) forbid the tip below ``tb_zone_z`` outside
the zone box; a joint move (MoveJ, MoveAbsJ) sweeps the tip along a curve nobody programs,
and with the rest pose (the pusher folded behind the body's front) and the 184.2 mm
pusher, a joint move from rest straight to a point over the table swings the tip under
the zone's ceiling outside the box (the model: (88, 299, 49) mm on the way to the left
table box's far inner corner (470, 50) at travel height;
tests/drivers/test_yumi_paths_zones.py).

So the only joint moves are between the rest pose and the arm's *gate*: a point at clear
height ``z_clear_mm`` over the table box (or the calibration's ``gate_xy_mm``), whose
joint path from rest the layout check proves clear of the zones. Where by default: half
way into the box from its near edge, five eighths out from its inner edge (the shipped
left box, y 75 to 370: about (310, 259); the figures below were measured on the whole
workspace, y 50 to 370, whose gate is (310, 250); on the shipped box ``testbed check``
reports 38 mm clear on the joint moves). Why, with the model, from the rest pose
(``sim_twin/yumi_geometry.py``'s ``REST_JOINTS_DEG``: ABB's folded arm and wrist, axis 1
swung back 40 deg, axis 2 at -90) and the 184.2 mm pusher:

- a gate near the box's inner near corner (a quarter in, (230, 130, 100)) skims the
  zone's ceiling outside the box on the joint move: the tip 1 mm over ``tb_zone_z`` at
  (123, 200, 81), a zone stop on a robot a few mm off the model;
- from (310, 250) the joint moves keep 40 mm clear (the tip never under z 120 outside the
  zone box; from the box's centre (310, 210): 36 mm) and every straight leg reaches its
  corner (tests/drivers/test_yumi_paths_zones.py).

The layout check sweeps the lab's own gate and FAULTs with the worst point.

Everything else is a straight line (MoveL) inside the zone box: from the gate straight to
above the target at travel height (a slant: clear height is needed where a joint move
starts or ends, not over the box), down and up where the push is, and from travel height
straight back to the gate. The column over the zone box above the floor is convex and the
zones leave it free: a straight line between two points in it stays in it, so no straight
leg can enter a zone. (Across at clear height first, then down, as before: from a gate
out in the box the line to the box's inner near edge at clear height runs past a joint
limit, (150, 64, 100) by 0.1 deg, (150, 124, 100) by 1.1 deg; at travel height it does
not.)

    rest --MoveJ--> gate (z_clear) --MoveL--> above the target (z_travel) --MoveL--> down
    ... up --MoveL--> z_travel --MoveL--> gate (z_clear) --MoveAbsJ--> rest

An arm found away from rest (a calibration point, a stopped program) first goes straight
up to travel height where it is, straight to the gate, and by joints to rest: the way
back retraces the way out, so axis 4 comes back unwound (``drivers/yumi/backend.py``,
``_from_here``, says why).

Why not higher: with the pusher pointing down, the IRB 14000 cannot hold a 184 mm tool
much above the table near its body (the model: over the left box's inner near corner
(150, 50) no higher than z 100-110; over its centre no higher than 150), so a clear
height of 200 mm is out of reach for most of the box; 100 (``tb_zone_z`` 80 + 20) is not.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

from drivers.yumi.yumi_controller import Waypoint

__all__ = ["DEFAULT_Z_CLEAR_MM", "GATE_DEPTH_FRACTION", "GATE_WIDTH_FRACTION", "gate_xy",
           "leave_rest", "to_rest"]

DEFAULT_Z_CLEAR_MM: Final = 100.0
"""The clear height when a calibration does not say: the shipped ``tb_zone_z`` (80) plus
the 20 mm margin ``testbed check`` wants (``drivers/yumi/controller_state.py``)."""
GATE_DEPTH_FRACTION: Final = 0.5
"""How far into the table box the default gate lies from its near edge, as a share of
the box's depth (see the module's docstring for why)."""
GATE_WIDTH_FRACTION: Final = 0.625
"""How far out from the table box's inner edge (nearer the body's centre line) the
default gate lies, as a share of the box's width."""


def gate_xy(box: Sequence[float], gate: Sequence[float] | None = None
            ) -> tuple[float, float]:
    """The arm's gate (x, y) mm: ``gate`` when the calibration gives one, else
    :data:`GATE_DEPTH_FRACTION` into ``box`` (x0, y0, x1, y1) from its near edge (x0,
    towards the body) and :data:`GATE_WIDTH_FRACTION` from its inner edge (the y edge
    nearer the body's centre line, y = 0)."""
    if gate is not None:
        return (float(gate[0]), float(gate[1]))
    x0, y0, x1, y1 = (float(v) for v in box)
    gx = x0 + GATE_DEPTH_FRACTION * (x1 - x0)
    if abs(y0) <= abs(y1):  # the inner edge is y0 (a left arm's box, y > 0)
        return (gx, y0 + GATE_WIDTH_FRACTION * (y1 - y0))
    return (gx, y1 - GATE_WIDTH_FRACTION * (y1 - y0))


def leave_rest(gate: Sequence[float], target_xy: Sequence[float], z_clear_mm: float,
               z_travel_mm: float, speed_mm_s: float) -> list[Waypoint]:
    """From rest: by joints to the gate at clear height, then straight to above
    ``target_xy`` at travel height. Both points stop exactly (``fine``): the joint path
    the layout check swept starts and ends there, no corner of a zone is cut."""
    return [Waypoint("move_j", (float(gate[0]), float(gate[1]), z_clear_mm), speed_mm_s),
            Waypoint("move_l", (float(target_xy[0]), float(target_xy[1]), z_travel_mm),
                     speed_mm_s)]


def to_rest(gate: Sequence[float], z_clear_mm: float, speed_mm_s: float) -> list[Waypoint]:
    """To rest from over the table box (at travel height or above): straight to the
    gate at clear height, then by joints (MoveAbsJ) to the rest pose."""
    return [Waypoint("move_l", (float(gate[0]), float(gate[1]), z_clear_mm), speed_mm_s),
            Waypoint("rest", None, speed_mm_s)]
