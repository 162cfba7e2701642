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

So the only joint moves are between the rest pose and the arm's *gate*, and both ends
are measured joint targets (MoveAbsJ): ``rest_joints_deg`` and ``gate_joints_deg`` of the
calibration. A joint move between two joint vectors is what the controller runs (every
joint linearly, all together) and exactly what the layout check computes
(``drivers/yumi/path_sweep.py``): the robot has no configuration to choose. (Before issue
43 the gate was a MoveJ to a robtarget with ConfJ off, and the controller took whichever
configuration it liked, one the sweep never saw.) The gate's point is at clear height
``z_clear_mm`` over the table box (the calibration's ``gate_xy_mm``, or by default: half
way into the box from its near edge, five eighths out from its inner edge; the shipped
left box, y 75 to 370: about (310, 259)); ``testbed calibrate`` measures its joints:
the first time the arm goes there by a MoveJ to the point (the controller's own solution,
its arm angle as the robot holds it) and the joints the controller then reports are
written as ``gate_joints_deg``; every move to the gate after that is a MoveAbsJ to them
(``backend.py``, ``_measure_gate``). ``testbed check`` FAULTs a file without them, or
whose joints do not put the pusher's tip over the table box at clear height, and the
driver refuses to move the arm (``drivers/yumi/gate.py``).
Why there, with the model, from the rest pose (``sim_twin/yumi_geometry.py``'s
``REST_JOINTS_DEG``: ABB's folded arm and wrist, axis 1 swung back 40 deg, axis 2 at -90)
and the 184.2 mm pusher (the figures measured on the whole workspace, y 50 to 370, whose
gate is (310, 250)):

- a gate near the box's inner near corner (a quarter in, (230, 130, 100)) skims the
  zone's ceiling outside the box on the joint move: the tip 1 mm over ``tb_zone_z`` at
  (123, 200, 81), a zone stop on a robot a few mm off the model;
- from (310, 250) the joint moves keep 40 mm clear (the tip never under z 120 outside the
  zone box; from the box's centre (310, 210): 36 mm) and every straight leg reaches its
  corner (tests/drivers/test_yumi_paths_zones.py).

The layout check sweeps the lab's own gate and FAULTs with the worst point. On the shipped
boxes (y 75 to 370, the gate about (310, 259)) it reports, the tip and the links: 38 mm
clear on the joint moves from rest and back, 72 mm on the correction from the worst of
the gate pose's solutions at the gate's arm angle, 17 mm on the straight legs (the
gripper over the far outer corner, (478, 342, 81): the wrist turned evenly along a
SingArea Wrist line tilts it out; the table box lies 25 mm inside the zone box). Each
leg holds the arm angle its robtarget carries (issue 43: ``eax_a`` is ABB's arm angle,
not axis 7's value; docs/notes/rws.md; ``drivers/yumi/line_plan.py`` plans it): every
corner's path runs but the inner near corner's, (150, +-75), which no line from the gate
reaches at any arm angle (the nearest solution there is past axis 2's or 7's limit), a
FAULT of the shipped layout; ``testbed calibrate``'s grid point nearest it, (160, +-85),
is refused before the arm moves (tests/drivers/test_yumi_rws_twin.py).

Everything else is a straight line (MoveL) inside the zone box: from the gate straight to
above the target at travel height (a slant: clear height is needed where a joint move
starts or ends, not over the box), down and up where the push is, and from travel height
straight back to the gate's point. The column over the zone box above the floor is
convex and the zones leave it free: a straight line between two points in it stays in
it, so no straight leg can enter a zone. (Across at clear height first, then down, as
before: from a gate out in the box the line to the box's inner near edge at clear height
runs past a joint limit, (150, 64, 100) by 0.1 deg, (150, 124, 100) by 1.1 deg; at travel
height it does not.)

Back at the gate's point, the arm's joints are whichever of that pose's few solutions the
lines took it to (our RAPID runs lines with ConfL Off and SingArea Wrist: with the pusher
down the wrist passes near its singularity over parts of the box and axes 4 and 6 turn
through it; on the twin a push's way back ends in the gate's own joints or in another
solution, axis 4 turned by 170 deg or a whole turn). So a MoveAbsJ to the gate joints
follows (the *correction*: a turn between two solutions of one pose, the pusher's tip
where both hold it), and only then the MoveAbsJ to rest, the swept joint move in
reverse. ``testbed check`` sweeps the correction from every solution of the gate's pose
within the joint limits, whichever the controller arrives in.

    rest --MoveAbsJ--> gate joints --MoveL--> above the target (z_travel) --MoveL--> down
    ... up --MoveL--> z_travel --MoveL--> the gate's point (z_clear)
        --MoveAbsJ--> gate joints --MoveAbsJ--> rest

An arm found away from rest is judged by its joints (``drivers/yumi/arm_place.py``): at
the gate it goes on from there; on a straight leg of the column (a program that was
stopped, a calibration point) it goes straight up to travel height where it is, straight
to the gate's point, and by the correction to the gate joints (:func:`back_to_gate`: the
way down retraced, the lines a push's return runs); anywhere else it is refused before
anything is sent, with the fix (jog it to rest).

Why not higher: with the pusher pointing down, the IRB 14000 cannot hold a 184 mm tool
much above the table near its body (the model: over the left box's inner near corner
(150, 50) no higher than z 100-110; over its centre no higher than 150), so a clear
height of 200 mm is out of reach for most of the box; 100 (``tb_zone_z`` 80 + 20) is not.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

from drivers.yumi.yumi_controller import Waypoint

__all__ = ["DEFAULT_Z_CLEAR_MM", "GATE_DEPTH_FRACTION", "GATE_WIDTH_FRACTION",
           "back_to_gate", "gate_xy", "leave_rest", "to_rest"]

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


def leave_rest(gate_joints: Sequence[float], target_xy: Sequence[float],
               z_travel_mm: float, speed_mm_s: float) -> list[Waypoint]:
    """From rest: by joints (MoveAbsJ) to the gate joints, then straight to above
    ``target_xy`` at travel height. Both stop exactly (``fine``): the joint path the
    layout check swept starts and ends there, no corner of a zone is cut."""
    return [Waypoint("abs_j", None, speed_mm_s, joints_deg=_joints(gate_joints)),
            Waypoint("move_l", (float(target_xy[0]), float(target_xy[1]), z_travel_mm),
                     speed_mm_s)]


def to_rest(gate: Sequence[float], gate_joints: Sequence[float], z_clear_mm: float,
            speed_mm_s: float) -> list[Waypoint]:
    """To rest from over the table box (at travel height or above): straight to the
    gate's point at clear height, by joints to the gate joints (the correction: see the
    module's docstring), then by joints (MoveAbsJ) to the rest pose."""
    return [Waypoint("move_l", (float(gate[0]), float(gate[1]), z_clear_mm), speed_mm_s),
            Waypoint("abs_j", None, speed_mm_s, joints_deg=_joints(gate_joints)),
            Waypoint("rest", None, speed_mm_s)]


def back_to_gate(here: Sequence[float], gate: Sequence[float], gate_joints: Sequence[float],
                 z_travel_mm: float, z_clear_mm: float, speed_mm_s: float,
                 lift_speed_mm_s: float, lift_tolerance_mm: float) -> list[Waypoint]:
    """From ``here`` on a straight leg of the column over the table box to the gate
    joints: straight up to travel height where it is (when more than
    ``lift_tolerance_mm`` below it, at ``lift_speed_mm_s``: the way down retraced),
    straight to the gate's point at clear height, and the correction to the gate joints."""
    x, y, z = (float(v) for v in here)
    lift = [Waypoint("move_l", (x, y, z_travel_mm), lift_speed_mm_s)
            ] if z < z_travel_mm - lift_tolerance_mm else []
    return [*lift, *to_rest(gate, gate_joints, z_clear_mm, speed_mm_s)[:2]]


def _joints(joints: Sequence[float]) -> tuple[float, ...]:
    out = tuple(float(v) for v in joints)
    if len(out) != 7:
        raise ValueError(f"a joint target needs 7 angles (axes 1-6, then 7), got {len(out)}")
    return out
