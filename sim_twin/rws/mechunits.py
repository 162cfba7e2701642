"""The YuMi's mechanical units as RWS reports them: ``robtarget`` for any tool and work
object, and ``jointtarget``.

Why it exists: the ABB client reads an arm's position with ``get_robtarget(mechunit,
tool, wobj, coordinate)``; a controller answers the TCP of the NAMED tool (the flange
moved by the tool's ``tframe``) in the base frame or in the work object's frame. The
twin computes the same from a pose source (the flange of each unit) and the ``tooldata``
and ``wobjdata`` symbols of the unit's task, so a client reading with the wrong tool sees
the wrong point, as it would on the robot.

Units: mm, quaternions ``[w, x, y, z]`` (RAPID's ``q1..q4``). The twin has no
kinematics of its own: ``jointtarget`` answers what the pose source says (by default a
fixed pose per arm), unrelated to the flange. A YuMi arm has 7 axes: a jointtarget's
``eax_a`` is axis 7's value; a robtarget's ``eaxa`` is ABB's arm angle of the joints
(``sim_twin/sew_angle.py``; docs/notes/rws.md, "What eax_a means on a YuMi"), as on an
IRB 14000 under RobotWare's arm-angle definition.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from sim_twin.rws.errors import GENERIC, refused
from sim_twin.rws.rapid_data import format_number, tool_frame, wobj_frames

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
TOOL_DOWN: Quat = (0.0, 0.0, 1.0, 0.0)
"""The flange turned so the tool's z points down (half a turn about y)."""
UNSET = 9e9
"""RAPID's value of an external axis that does not exist."""


@dataclass(frozen=True)
class MechUnit:
    name: str
    """RWS name: ``ROB_L``, ``ROB_R``."""
    task: str
    """The RAPID motion task that drives it: ``T_ROB_L``, ``T_ROB_R``."""
    arm: str
    """The cell's arm name: ``left``, ``right``."""


YUMI_UNITS = (MechUnit("ROB_L", "T_ROB_L", "left"), MechUnit("ROB_R", "T_ROB_R", "right"))


def qmul(a: Sequence[float], b: Sequence[float]) -> Quat:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def qnorm(q: Sequence[float]) -> Quat:
    n = math.sqrt(sum(c * c for c in q))
    if not n > 0:
        raise ValueError("a rotation quaternion must not be zero")
    w, x, y, z = (c / n for c in q)
    return (w, x, y, z)


def qconj(q: Sequence[float]) -> Quat:
    return (q[0], -q[1], -q[2], -q[3])


def qrot(q: Sequence[float], v: Sequence[float]) -> Vec3:
    _, x, y, z = qmul(qmul(q, (0.0, v[0], v[1], v[2])), qconj(q))
    return (x, y, z)


def _compose(p: Vec3, q: Quat, t: Sequence[float], r: Sequence[float]) -> tuple[Vec3, Quat]:
    """Frame ``(p, q)`` followed by ``(t, r)`` expressed in it."""
    d = qrot(q, t)
    return (p[0] + d[0], p[1] + d[1], p[2] + d[2]), qnorm(qmul(q, r))


def _inverse_apply(frame: tuple[Vec3, Quat], p: Vec3, q: Quat) -> tuple[Vec3, Quat]:
    """``(p, q)`` (base frame) seen from ``frame``."""
    fp, fq = frame
    inv = qconj(fq)
    return qrot(inv, (p[0] - fp[0], p[1] - fp[1], p[2] - fp[2])), qnorm(qmul(inv, q))


class PoseSource(Protocol):
    """Where the twin's arms are: each unit's flange, joints and configuration."""

    def flange(self, unit: MechUnit) -> tuple[Vec3, Quat]: ...

    def joints(self, unit: MechUnit) -> tuple[float, ...]: ...

    def robconf(self, unit: MechUnit) -> tuple[float, float, float, float]: ...

    def arm_angle(self, unit: MechUnit) -> float:
        """ABB's arm angle (deg) of the unit's joints: a robtarget's ``eaxa``."""
        ...


class StaticPoses:
    """Poses set by hand (tests, a twin without a cell). Defaults: each arm's flange
    above the cell's rest point with the tool down, a fixed 7-axis pose."""

    def __init__(self, units: Sequence[MechUnit] = YUMI_UNITS) -> None:
        self._lock = threading.Lock()
        side = {u.name: (1.0 if u.arm == "left" else -1.0) for u in units}
        self._flange: dict[str, tuple[Vec3, Quat]] = {
            u.name: ((100.0, 450.0 * side[u.name], 150.0), TOOL_DOWN) for u in units}
        self._joints: dict[str, tuple[float, ...]] = {
            # ABB's home with ABB's arm-angle signs (public YuMi RAPID: left +135, right -135)
            u.name: (0.0, -130.0, 30.0, 0.0, 40.0, 0.0, 135.0 * side[u.name]) for u in units}
        self._conf = {u.name: (0.0, 0.0, 0.0, 4.0) for u in units}

    def set_flange(self, unit: str, xyz: Sequence[float], quat: Sequence[float] = TOOL_DOWN
                   ) -> None:
        with self._lock:
            self._flange[unit] = ((float(xyz[0]), float(xyz[1]), float(xyz[2])), qnorm(quat))

    def set_joints(self, unit: str, joints: Sequence[float]) -> None:
        with self._lock:
            self._joints[unit] = tuple(float(j) for j in joints)

    def flange(self, unit: MechUnit) -> tuple[Vec3, Quat]:
        with self._lock:
            return self._flange[unit.name]

    def joints(self, unit: MechUnit) -> tuple[float, ...]:
        with self._lock:
            return self._joints[unit.name]

    def robconf(self, unit: MechUnit) -> tuple[float, float, float, float]:
        with self._lock:
            return self._conf[unit.name]

    def arm_angle(self, unit: MechUnit) -> float:
        """The arm angle of :meth:`joints` on the twin's arm model (a unit that is not a
        YuMi arm: its 7th joint, there being no arm angle to tell)."""
        from sim_twin.sew_angle import arm_angle
        from sim_twin.yumi_arms import ArmModel, abb_to_chain

        joints = self.joints(unit)
        if unit.arm not in ("left", "right") or len(joints) < 7:
            return joints[6] if len(joints) > 6 else UNSET
        return arm_angle(ArmModel(unit.arm).pose(abb_to_chain(joints)))


def robtarget_item(unit: MechUnit, poses: PoseSource, tool_value: str, wobj_value: str,
                   coordinate: str) -> dict[str, Any]:
    """The ``ms-robtargets`` item: the TCP of the tool, in base (= world) or wobj frame."""
    coord = coordinate.lower()
    if coord not in ("base", "world", "wobj"):
        raise refused(400, GENERIC, f"coordinate={coordinate!r}: the twin answers Base, "
                                    "World (= Base) and Wobj")
    fp, fq = poses.flange(unit)
    t, r = tool_frame(tool_value)
    p, q = _compose(fp, fq, t, r)
    if coord == "wobj":
        (ut, ur), (ot, orot) = wobj_frames(wobj_value)
        up, uq = _compose((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), ut, ur)
        frame = _compose(up, uq, ot, orot)
        p, q = _inverse_apply(frame, p, q)
    joints = poses.joints(unit)
    ext = [poses.arm_angle(unit) if len(joints) > 6 else UNSET] + [UNSET] * 5
    conf = poses.robconf(unit)
    item: dict[str, Any] = {"_type": "ms-robtargets", "_title": unit.name}
    item.update({k: _num(v) for k, v in zip("xyz", p, strict=True)})
    item.update({f"q{i + 1}": _num(v) for i, v in enumerate(q)})
    item.update({k: _num(v) for k, v in zip(("cf1", "cf4", "cf6", "cfx"), conf, strict=True)})
    item.update({f"eax{c}": _num(v) for c, v in zip("abcdef", ext, strict=True)})
    return item


def jointtarget_item(unit: MechUnit, poses: PoseSource) -> dict[str, Any]:
    j = list(poses.joints(unit))
    rob = (j + [0.0] * 6)[:6]
    ext = (j[6:] + [UNSET] * 6)[:6]
    item: dict[str, Any] = {"_type": "ms-jointtarget", "_title": unit.name}
    item.update({f"rax_{i + 1}": _num(v) for i, v in enumerate(rob)})
    item.update({f"eax_{c}": _num(v) for c, v in zip("abcdef", ext, strict=True)})
    return item


def _num(v: float) -> str:
    return format_number(round(float(v), 6)) if abs(v) < 1e9 else format_number(float(v))


def unit_by_name(units: Mapping[str, MechUnit], name: str) -> MechUnit:
    unit = units.get(name.upper())
    if unit is None:
        raise refused(404, GENERIC, f"no mechanical unit {name!r} (this twin has "
                                    f"{sorted(units)})")
    return unit
