"""Where an arm is, judged from the joints the controller reports: at rest, at its gate,
on a straight leg over its table box, or somewhere the driver will not move it from.

Why joints: every program the driver sends starts with a joint move from rest or the way
back to rest (``drivers/yumi/paths.py``), and a joint move's path depends on every joint
at its start. Before issue 43 "at rest" was the model's tip within 10 mm of the rest
point, which says nothing of the joints (a person's jog, a wrist turned over): a MoveAbsJ
to rest from there sweeps a path nobody checked. So an arm is:

- at rest when every joint is within :data:`JOINT_TOLERANCE_DEG` of ``rest_joints_deg``;
- at the gate when every joint is within it of ``gate_joints_deg``;
- on a straight leg when the pusher's tip (the controller's ``tool_pusher`` in
  ``wobj0``) is in the column over the table box, from the floor to clear height (both
  :data:`COLUMN_TOLERANCE_MM`), and the pusher within :data:`TILT_TOLERANCE_DEG` of the
  direction every leg holds it in (the model's forward kinematics of the joints read):
  the pose a program stopped on a leg leaves, or a calibration point. Its way back runs
  in that column (straight lines: no zone in it) to the gate's point, and from there the
  correction, a joint move from whichever solution of the gate's pose the lines arrived
  in (``testbed check`` sweeps each: ``drivers/yumi/gate.py``);
- anywhere else: refused before anything is sent, with the fix.

Why not the configuration (axes 4 and 6 quadrants, as a robtarget's confdata): the
driver's own legs change it. With the pusher down the wrist passes near its singularity
over parts of the box and SingArea Wrist turns axes 4 and 6 through it; on the twin,
along the calibration's grid over the shipped right box, axis 4 runs from -43 to 235 deg
while the gate's is 101. A rule on the quadrants would refuse the driver's own poses;
what keeps the way back from one safe is the column and the swept correction. Nor axis
7 against the calibration's arm angle: a robtarget's ``eax_a`` is the arm angle as the
controller defines it (the elbow's plane, not axis 7's value: docs/notes/rws.md), so
axis 7 itself changes along a leg.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np

from drivers.errors import BackendError
from drivers.yumi.reach import ArmTool

__all__ = ["COLUMN_TOLERANCE_MM", "JOINT_TOLERANCE_DEG", "TILT_TOLERANCE_DEG", "ArmRoom",
           "Place", "place_of"]

JOINT_TOLERANCE_DEG: Final = 0.1
"""Every joint this close to the rest (or gate) joints: the arm is there. Why 0.1: a
joint move from joints within it of the swept start stays within it of the swept path
at every instant (linear interpolation: the offset shrinks to 0 at the end), and at rest
and at the gate the seven axes' lever arms to the pusher's tip sum to about 1.8 m per
radian (the model, 184.2 mm pusher), so 0.1 deg on all of them moves the tip at most
about 3 mm: a sixth of the joint moves' 20 mm margin to the zones
(``layout_check.JOINT_MARGIN_MM``). A controller reports the joints of a MoveAbsJ
``fine`` end to a few thousandths of a degree, and the FlexPendant's jog to a stored
jointtarget ends on it: 0.1 is wide for those and narrow for a jog by eye."""
COLUMN_TOLERANCE_MM: Final = 1.0
"""How far outside the table box's column (its edges, the floor, clear height) a tip may
read and still be on a leg: the controller's own jitter (as the backend's
``LIFT_TOLERANCE_MM``)."""
TILT_TOLERANCE_DEG: Final = 30.0
"""How far the pusher may point from the legs' direction (down) on a leg: SingArea Wrist
lets the tool's orientation "differ somewhat" between a line's ends (ABB's words); the
twin's lines over the shipped boxes tilt it by up to 15 deg mid-line."""

Kind = Literal["rest", "gate", "leg"]
FIX = "jog it to rest on the FlexPendant (manual reduced speed), then PP to Main"


@dataclass(frozen=True)
class ArmRoom:
    """What the judgement needs of one arm's calibration."""

    rest_joints_deg: Sequence[float]
    gate_joints_deg: Sequence[float] | None
    table_box_mm: Sequence[float]
    z_clear_mm: float
    tool: ArmTool | None
    """The arm's model and tool (None: not an IRB 14000 arm the model knows: the tilt
    is not judged)."""


@dataclass(frozen=True)
class Place:
    """Where an arm is: ``kind`` and the tip the controller reported."""

    kind: Kind
    tcp_mm: tuple[float, float, float]


def _near(a: Sequence[float], b: Sequence[float] | None) -> bool:
    return b is not None and len(a) == len(b) and all(
        abs(float(x) - float(y)) <= JOINT_TOLERANCE_DEG for x, y in zip(a, b, strict=True))


def _off_leg(room: ArmRoom, tcp: Sequence[float], joints: Sequence[float]) -> str | None:
    """Why an arm is not on a straight leg of the column, or None."""
    x, y, z = (float(v) for v in tcp)
    x0, y0, x1, y1 = (float(v) for v in room.table_box_mm)
    tol = COLUMN_TOLERANCE_MM
    if not (x0 - tol <= x <= x1 + tol and y0 - tol <= y <= y1 + tol):
        return f"the tip is outside the table box {tuple(room.table_box_mm)}"
    if not -tol <= z <= room.z_clear_mm + tol:
        return f"the tip is not between the table and clear height {room.z_clear_mm:g} mm"
    if room.tool is not None:
        flange = room.tool.model.pose_abb(joints).flange[:3, 2]
        cos = float(np.clip(flange @ room.tool.rotation[:, 2], -1.0, 1.0))
        tilt = math.degrees(math.acos(cos))
        if tilt > TILT_TOLERANCE_DEG:
            return (f"the pusher points {tilt:.0f} deg from the legs' direction (want "
                    f"{TILT_TOLERANCE_DEG:g})")
    if room.gate_joints_deg is None:
        return "its calibration has no gate_joints_deg to go back through"
    return None


def place_of(arm: str, room: ArmRoom, tcp: Sequence[float], joints: Sequence[float]
             ) -> Place:
    """Where ``arm`` is (see the module's docstring), or a :class:`BackendError` naming
    the arm, its joints and the fix, for an arm the driver will not move."""
    here = (float(tcp[0]), float(tcp[1]), float(tcp[2]))
    if len(joints) != 7 or not all(math.isfinite(float(v)) for v in joints):
        raise BackendError(f"arm {arm}: the controller reported joints {list(joints)}, not "
                           f"7 angles; nothing was sent")
    if _near(joints, room.rest_joints_deg):
        return Place("rest", here)
    if _near(joints, room.gate_joints_deg):
        return Place("gate", here)
    why = _off_leg(room, here, joints)
    if why is None:
        return Place("leg", here)
    shown = "[" + ", ".join(f"{float(v):.1f}" for v in joints) + "]"
    raise BackendError(
        f"arm {arm} is where the driver will not move it from: joints {shown} deg, the "
        f"pusher's tip at ({here[0]:.0f}, {here[1]:.0f}, {here[2]:.0f}) mm; not at rest "
        f"nor at its gate (every joint within {JOINT_TOLERANCE_DEG:g} deg), nor on a "
        f"straight leg over its table box ({why}); nothing was sent: {FIX}")
