"""The YuMi's two arms in the hardware twin: IRB 14000 kinematics, joint limits, link shapes.

Why the twin has arms: a twin whose pushers float reaches any target in any configuration,
so a layout the real arm cannot reach, a joint past its limit or two arms driven into
each other pass the rehearsal and stop the robot on day one. With these arms the twin's
controller solves every target as the controller would, refuses what the robot would
refuse (:mod:`sim_twin.rws.arm_supervision` names the controller's errors), and watches the
links' distance to each other and to the table along every path.

Where the numbers come from: each arm is a 7-axis chain, ABB's axis order along it being
1, 2, 7, 3, 4, 5, 6 (axis 7 is the third joint; a jointtarget's ``eax_a`` is its value, a
robtarget's ``eax_a`` is ABB's arm angle, another number: :mod:`sim_twin.sew_angle`). The
joint origins (translation mm, roll-pitch-yaw rad, each joint turning about its own z) and
each arm's base on the body are the public robot description of the IRB 14000
(OrebroUniversity/yumi, ``yumi_description/urdf/yumi.urdf``: ``yumi_joint_1_l`` at
(53.55, 72.5, 414.92) mm, rpy (0.9781, -0.5716, 2.3180), the right arm mirrored); the
link lengths agree with ABB's published modified Denavit-Hartenberg parameters of the
same arm (upper arm 251.5 mm, forearm 265 mm, offsets 30, 40.5 and 27 mm, flange 36 mm).
The joint ranges are ABB's product specification of the IRB 14000 (axis 1 and 7 +-168.5
deg, 2 -143.5..+43.5, 3 -123.5..+80, 4 +-290, 5 -88..+138, 6 +-229), as the description's
limits. Joint zero is the description's, taken as ABB's calibration position (day one:
jog every axis to 0 and compare, docs/rws-checklist.md). The link radii are ours: each
link a capsule that covers the arm's casing as drawn in ABB's dimension drawings, to the
nearest 5 mm (the sizes are in :data:`LINK_RADII_MM`).

This model is the twin's own: the operator's side has its own (``drivers/yumi/``), written
separately from the same published numbers, so an error in one is not hidden by the other
(a test compares them). Frames: the cell's base frame, mm (``sim_twin.yumi_geometry``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

Mat = npt.NDArray[np.float64]
H: Final = math.pi / 2

CHAIN_AXES: Final = (1, 2, 7, 3, 4, 5, 6)
"""ABB's axis number of each joint along the chain."""
_LINKS: Final = (  # (xyz mm, rpy rad) of joint k+1's origin in joint k's frame; last: flange
    ((30.0, 0.0, 100.0), (H, 0.0, 0.0)),
    ((-30.0, 172.83, 0.0), (-H, 0.0, 0.0)),
    ((-41.88, 0.0, 78.73), (H, -H, 0.0)),
    ((40.5, 164.61, 0.0), (-H, 0.0, 0.0)),
    ((-27.0, 0.0, 100.39), (H, 0.0, 0.0)),
    ((27.0, 29.0, 0.0), (-H, 0.0, 0.0)),
    ((0.0, 0.0, 7.0), (0.0, 0.0, 0.0)),
)
BASES: Final = {
    "left": ((53.55, 72.5, 414.92), (0.9781, -0.5716, 2.3180)),
    "right": ((53.55, -72.5, 414.92), (-0.9795, -0.5682, -2.3155)),
}
"""Each arm's joint 1 on the body (the base frame), as the description gives it."""
LIMITS_DEG: Final = {1: (-168.5, 168.5), 2: (-143.5, 43.5), 7: (-168.5, 168.5),
                     3: (-123.5, 80.0), 4: (-290.0, 290.0), 5: (-88.0, 138.0),
                     6: (-229.0, 229.0)}
"""ABB's axis ranges (product specification), by axis number."""
LINK_RADII_MM: Final = (55.0, 45.0, 45.0, 40.0, 38.0, 35.0, 35.0)
"""Capsule radius of the link after each joint (the last: wrist to flange)."""
GRIPPER_MM: Final = (60.0, 40.0)
"""The gripper's body, which holds the pusher: a capsule this long from the flange, this
radius (our estimate of the YuMi gripper's housing; its fingers and the pusher below it
are the pusher's capsule)."""
PUSHER_RADIUS_MM: Final = 12.0
DEFAULT_TOOL_MM: Final = 184.2
"""The hardware twin's pusher when none is given: its tip 184.2 mm from the flange along
the flange's z (ABB's servo-gripper finger TCP at 114.2 mm, plus the 100 mm rod held 30 mm
inside the fingers, 70 mm beyond them): the one pusher length of the project, the
controller's ``tool_pusher`` as shipped (robot/README.md)."""


def _rpy(r: float, p: float, y: float) -> Mat:
    cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p),
                              math.cos(y), math.sin(y))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _frame(xyz: Sequence[float], rpy: Sequence[float]) -> Mat:
    m = np.eye(4)
    m[:3, :3] = _rpy(*rpy)
    m[:3, 3] = xyz
    return m


_OFFSETS: Final = tuple(_frame(*link) for link in _LINKS)
_OFFSET_STACK: Final = np.stack(_OFFSETS)
REACH_MM: Final = float(sum(math.hypot(*xyz) for xyz, _ in _LINKS[1:]))
"""The farthest the flange can be from axis 2's origin (584.7 mm: every link from there
in a line; the joints' ranges allow 580 at most, sampled): a bound, never an estimate."""


def abb_to_chain(joints_deg: Sequence[float]) -> list[float]:
    """ABB's joint order (axes 1..6, then 7: ``rax_1..6, eax_a``) -> chain order, deg."""
    j = list(joints_deg)
    return [j[0], j[1], j[6], j[2], j[3], j[4], j[5]]


def chain_to_abb(chain_deg: Sequence[float]) -> list[float]:
    c = list(chain_deg)
    return [c[0], c[1], c[3], c[4], c[5], c[6], c[2]]


@dataclass(frozen=True)
class ArmPose:
    """One arm's joint frames for a chain angle vector: ``frames[k]`` is joint k's frame
    (its z the joint axis), ``frames[7]`` the flange (its z the tool direction)."""

    chain_deg: tuple[float, ...]
    frames: Mat

    @property
    def flange(self) -> Mat:
        return self.frames[7]


class ArmModel:
    """One IRB 14000 arm: forward kinematics, the Jacobian, limits and link capsules."""

    def __init__(self, side: str) -> None:
        if side not in BASES:
            raise ValueError(f"a YuMi arm is 'left' or 'right', got {side!r}")
        self.side = side
        self.base = _frame(*BASES[side])
        self.lower = np.array([LIMITS_DEG[a][0] for a in CHAIN_AXES])
        self.upper = np.array([LIMITS_DEG[a][1] for a in CHAIN_AXES])

    def pose(self, chain_deg: Sequence[float]) -> ArmPose:
        """Joint k's frame is the last one turned by joint k's angle about its z, then
        offset: ``rot_z(q) @ offset`` is the offset with its rows 0 and 1 turned, made
        for the seven joints at once (the solvers ask this at every iteration)."""
        q = np.radians(np.asarray(chain_deg, dtype=np.float64))
        c, s = np.cos(q)[:, None], np.sin(q)[:, None]
        turned = _OFFSET_STACK.copy()
        turned[:, 0] = c * _OFFSET_STACK[:, 0] - s * _OFFSET_STACK[:, 1]
        turned[:, 1] = s * _OFFSET_STACK[:, 0] + c * _OFFSET_STACK[:, 1]
        frames = np.empty((8, 4, 4))
        m = self.base
        for k in range(7):
            frames[k] = m
            m = m @ turned[k]
        frames[7] = m
        return ArmPose(tuple(float(x) for x in chain_deg), frames)

    def frames_batch(self, chain_deg: npt.ArrayLike) -> Mat:
        """(N, 8, 4, 4): :meth:`pose`'s frames for N chain angle vectors (N, 7) at once
        (the inverse kinematics descends from many seeds together)."""
        q = np.radians(np.asarray(chain_deg, dtype=np.float64).reshape(-1, 7))
        n = q.shape[0]
        if n == 1:  # one: the plain chain is quicker
            return self.pose(np.degrees(q[0])).frames[None]
        frames = np.empty((n, 8, 4, 4))
        m = np.broadcast_to(self.base, (n, 4, 4)).copy()
        for k in range(7):
            frames[:, k] = m
            c, s = np.cos(q[:, k])[:, None], np.sin(q[:, k])[:, None]
            col0, col1 = m[:, :, 0].copy(), m[:, :, 1]
            m[:, :, 0] = c * col0 + s * col1  # m @ rot_z(q): only columns 0 and 1 turn
            m[:, :, 1] = c * col1 - s * col0
            m = m @ _OFFSETS[k]
        frames[:, 7] = m
        return frames

    def tip(self, chain_deg: Sequence[float], tool_mm: float) -> tuple[float, float, float]:
        """The pusher's tip (the cell's TCP): ``tool_mm`` along the flange's z."""
        f = self.pose(chain_deg).flange
        x, y, z = (float(v) for v in f[:3, 3] + f[:3, 2] * tool_mm)
        return (x, y, z)

    def jacobian(self, pose: ArmPose, point: npt.ArrayLike) -> Mat:
        """(6, 7): d(point, orientation)/d(joint angle in rad), the point on the flange's
        rigid body (the TCP)."""
        p = np.asarray(point, dtype=np.float64)
        z = pose.frames[:7, :3, 2]
        o = pose.frames[:7, :3, 3]
        d = p - o  # z x d row by row (np.cross costs more than the rest on 7 rows)
        zxd = np.stack([z[:, 1] * d[:, 2] - z[:, 2] * d[:, 1],
                        z[:, 2] * d[:, 0] - z[:, 0] * d[:, 2],
                        z[:, 0] * d[:, 1] - z[:, 1] * d[:, 0]], axis=1)
        return np.vstack([zxd.T, z.T])

    def reach_shortfall(self, point: npt.ArrayLike) -> float:
        """How far (mm) ``point`` lies beyond anything the flange can reach (<= 0: maybe
        reachable): its distance from the circle axis 2's origin turns on about axis 1,
        less :data:`REACH_MM`. The controller's quick "outside reach"."""
        p = np.linalg.solve(self.base, np.append(np.asarray(point, dtype=np.float64), 1.0))
        (ox, _, oz), _ = _LINKS[0]
        return math.hypot(math.hypot(p[0], p[1]) - ox, p[2] - oz) - REACH_MM

    def limit_violation(self, chain_deg: Sequence[float]) -> tuple[int, float] | None:
        """(ABB axis, degrees past its limit) of the worst joint out of range, or None."""
        q = np.asarray(chain_deg)
        over = np.maximum(self.lower - q, q - self.upper)
        k = int(np.argmax(over))
        return (CHAIN_AXES[k], float(over[k])) if over[k] > 1e-6 else None

    def capsules(self, pose: ArmPose, tool_z_mm: float) -> list[tuple[Mat, Mat, float]]:
        """The arm's shapes as (a, b, radius) segments, base frame mm: its links, then the
        gripper and the pusher (from the gripper's end to the TCP, the tool's z)."""
        pts = pose.frames[:, :3, 3]
        out = [(pts[k], pts[k + 1], LINK_RADII_MM[k]) for k in range(7)]
        down = pose.flange[:3, 2]
        grip = min(GRIPPER_MM[0], max(tool_z_mm - 10.0, 0.0))
        g_end = pts[7] + down * grip
        out.append((pts[7], g_end, GRIPPER_MM[1]))
        out.append((g_end, pts[7] + down * tool_z_mm, PUSHER_RADIUS_MM))
        return out


def segment_distance(a0: Mat, a1: Mat, b0: Mat, b1: Mat) -> float:
    """The smallest distance between two segments (closed), mm."""
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a, e, f = float(d1 @ d1), float(d2 @ d2), float(d2 @ r)
    if a < 1e-12 and e < 1e-12:
        return float(np.linalg.norm(r))
    if a < 1e-12:
        s, t = 0.0, min(max(f / e, 0.0), 1.0)
    else:
        c = float(d1 @ r)
        if e < 1e-12:
            s, t = min(max(-c / a, 0.0), 1.0), 0.0
        else:
            b = float(d1 @ d2)
            den = a * e - b * b
            s = min(max((b * f - c * e) / den, 0.0), 1.0) if den > 1e-12 else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                s, t = min(max(-c / a, 0.0), 1.0), 0.0
            elif t > 1.0:
                s, t = min(max((b - c) / a, 0.0), 1.0), 1.0
    return float(np.linalg.norm((a0 + d1 * s) - (b0 + d2 * t)))


def segment_distances(a0: Mat, a1: Mat, b0: Mat, b1: Mat) -> Mat:
    """:func:`segment_distance` of many pairs at once: (..., 3) arrays -> (...,)."""
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a, e = np.einsum("...i,...i", d1, d1), np.einsum("...i,...i", d2, d2)
    f, c, b = (np.einsum("...i,...i", d2, r), np.einsum("...i,...i", d1, r),
               np.einsum("...i,...i", d1, d2))
    a_ok, e_ok = a >= 1e-12, e >= 1e-12
    a_, e_ = np.where(a_ok, a, 1.0), np.where(e_ok, e, 1.0)
    den = a * e - b * b
    s = np.where(den > 1e-12, np.clip((b * f - c * e) / np.where(den > 1e-12, den, 1.0),
                                      0.0, 1.0), 0.0)
    t = (b * s + f) / e_
    s = np.where(t < 0.0, np.clip(-c / a_, 0.0, 1.0),
                 np.where(t > 1.0, np.clip((b - c) / a_, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    # the degenerate cases: a point against a segment, or two points
    s = np.where(~a_ok, 0.0, np.where(~e_ok, np.clip(-c / a_, 0.0, 1.0), s))
    t = np.where(~e_ok, 0.0, np.where(~a_ok, np.clip(f / e_, 0.0, 1.0), t))
    gap = (a0 + d1 * s[..., None]) - (b0 + d2 * t[..., None])
    return np.sqrt(np.einsum("...i,...i", gap, gap))


def clearance(left: Sequence[tuple[Mat, Mat, float]],
              right: Sequence[tuple[Mat, Mat, float]]) -> tuple[float, int, int]:
    """The smallest gap between two sets of capsules (negative: they overlap), mm, and
    the indices of the two shapes (every pair at once)."""
    la, lb = np.array([x[0] for x in left]), np.array([x[1] for x in left])
    ra, rb = np.array([x[0] for x in right]), np.array([x[1] for x in right])
    lr, rr = np.array([x[2] for x in left]), np.array([x[2] for x in right])
    gaps = segment_distances(la[:, None], lb[:, None], ra[None], rb[None]) - \
        lr[:, None] - rr[None]
    i, j = np.unravel_index(int(np.argmin(gaps)), gaps.shape)
    return float(gaps[i, j]), int(i), int(j)


def table_clearance(shapes: Sequence[tuple[Mat, Mat, float]]) -> tuple[float, int]:
    """The smallest height of a shape above the table top (z = 0), the pusher aside (its
    tip pushes cubes on the table: the world zones watch it), and which shape."""
    gaps = [min(float(a[2]), float(b[2])) - r for a, b, r in shapes[:-1]]
    k = int(np.argmin(gaps))
    return gaps[k], k


def rest_tip(side: str, tool_mm: float = DEFAULT_TOOL_MM) -> tuple[float, float, float]:
    """Where the arms' rest joints (``sim_twin.yumi_geometry.REST_JOINTS_DEG``) hold the
    pusher's tip: the twin's rest point for that side."""
    from sim_twin.yumi_geometry import REST_JOINTS_DEG

    return ArmModel(side).tip(abb_to_chain(REST_JOINTS_DEG[side]), tool_mm)
