"""The ABB IRB 14000 (YuMi) arms as 7-axis chains: joint frames, limits, forward kinematics.

Why the operator's side has a model of the arm: a layout the arm cannot reach (a table box
corner out of reach with the pusher down, a rest pose under the world zone's ceiling or
in the camera's view, two arms that meet on the way) stops the robot on day one, after
the trial has started. With the arm's numbers here, ``testbed check``, ``testbed
calibrate`` and the driver tell before anything moves (``drivers/yumi/irb14000_ik.py``
solves targets, ``drivers/yumi/arm_shapes.py`` measures clearances,
``drivers/yumi/layout_check.py`` words the FAULT lines). numpy only: this runs on a robot
host, which has no PyBullet or torch.

Where each number comes from (nothing here is copied from a file; the numbers are):

- The chain: ABB's axis order along each arm is 1, 2, 7, 3, 4, 5, 6 (axis 7, the arm
  angle, sits between the shoulder's two axes and the elbow): ABB's IRB 14000 product
  specification; the public robot description of the IRB 14000 (OrebroUniversity/yumi,
  ``yumi_description/urdf/yumi.urdf``, joints ``yumi_joint_1_l`` .. ``yumi_joint_6_l``)
  has the same order.
- Each joint's origin in the previous joint's frame (translation mm, roll-pitch-yaw rad;
  every joint turns about its own z) and each arm's axis 1 on the body (the shoulders:
  left at (53.55, 72.5, 414.92) mm, roll-pitch-yaw (0.9781, -0.5716, 2.3180); right at
  (53.55, -72.5, 414.92) mm, (-0.9795, -0.5682, -2.3155)): that description's
  ``<origin>`` of each joint. The lengths agree with ABB's: upper arm 172.83 + 78.73 =
  251.6 mm, forearm 164.61 + 100.39 = 265 mm. The body frame of the description is the
  robot's base frame (its foot on the table, x forward, z up), which is the robot's world
  frame (wobj0): the frame the driver's targets are in (docs/notes/yumi-real.md) and the
  cell's
  (``sim_twin/yumi_geometry.py``).
- The flange (``tool0``): 7 mm along axis 6 from its joint frame, where the description
  mounts the gripper (``yumi_link_7_l_joint``).
- Joint ranges: ABB's product specification (axis 1 and 7 +-168.5 deg, 2 -143.5..+43.5,
  3 -123.5..+80, 4 +-290, 5 -88..+138, 6 +-229); the description's ``<limit>`` values are
  the same angles in radians.
- Joint zero is the description's, taken as ABB's calibration position (jog every axis
  to 0 on day one and compare; robot/README.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

__all__ = ["ARMS", "CHAIN_AXES", "LIMITS_DEG", "Arm", "Pose", "abb_to_chain", "arm",
           "chain_to_abb"]

Mat = npt.NDArray[np.float64]
_Q: Final = math.pi / 2

CHAIN_AXES: Final = (1, 2, 7, 3, 4, 5, 6)
"""ABB's axis number of each joint along the chain, shoulder first."""
JOINT_ORIGINS: Final = (
    ((30.0, 0.0, 100.0), (_Q, 0.0, 0.0)),          # axis 2 in axis 1's frame
    ((-30.0, 172.83, 0.0), (-_Q, 0.0, 0.0)),       # axis 7 in axis 2's
    ((-41.88, 0.0, 78.73), (_Q, -_Q, 0.0)),        # axis 3 in axis 7's
    ((40.5, 164.61, 0.0), (-_Q, 0.0, 0.0)),        # axis 4 in axis 3's
    ((-27.0, 0.0, 100.39), (_Q, 0.0, 0.0)),        # axis 5 in axis 4's
    ((27.0, 29.0, 0.0), (-_Q, 0.0, 0.0)),          # axis 6 in axis 5's
    ((0.0, 0.0, 7.0), (0.0, 0.0, 0.0)),            # the flange in axis 6's
)
"""(xyz mm, rpy rad) of the next joint's frame in this one's (see the module docstring)."""
SHOULDERS: Final = {
    "left": ((53.55, 72.5, 414.92), (0.9781, -0.5716, 2.3180)),
    "right": ((53.55, -72.5, 414.92), (-0.9795, -0.5682, -2.3155)),
}
"""Each arm's axis 1 frame on the body (base frame, mm and rpy rad)."""
LIMITS_DEG: Final = {1: (-168.5, 168.5), 2: (-143.5, 43.5), 7: (-168.5, 168.5),
                     3: (-123.5, 80.0), 4: (-290.0, 290.0), 5: (-88.0, 138.0),
                     6: (-229.0, 229.0)}
"""ABB's axis ranges (IRB 14000 product specification), by ABB axis number."""
ARMS: Final = ("left", "right")


def rpy_matrix(roll: float, pitch: float, yaw: float) -> Mat:
    """Rotation of a fixed-axis roll (x), pitch (y), yaw (z): Rz @ Ry @ Rx, as a robot
    description's ``<origin rpy>`` means it."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def transform(xyz: Sequence[float], rpy: Sequence[float]) -> Mat:
    m = np.eye(4)
    m[:3, :3] = rpy_matrix(*rpy)
    m[:3, 3] = xyz
    return m


_ORIGINS: Final = tuple(transform(*o) for o in JOINT_ORIGINS)
_ORIGIN_STACK: Final = np.stack(_ORIGINS)


def abb_to_chain(abb_deg: Sequence[float]) -> list[float]:
    """ABB's joint order (``rax_1..rax_6``, then axis 7 as ``eax_a``) -> chain order."""
    j = [float(v) for v in abb_deg]
    if len(j) != 7:
        raise ValueError(f"an IRB 14000 arm has 7 joint angles, got {len(j)}")
    return [j[0], j[1], j[6], j[2], j[3], j[4], j[5]]


def chain_to_abb(chain_deg: Sequence[float]) -> list[float]:
    """Chain order -> ABB's (axes 1..6, then axis 7)."""
    c = [float(v) for v in chain_deg]
    return [c[0], c[1], c[3], c[4], c[5], c[6], c[2]]


@dataclass(frozen=True)
class Pose:
    """One arm at one joint vector: ``frames[k]`` is chain joint k's frame (its z the
    joint's axis, its origin on the axis), ``frames[7]`` the flange (z: the tool's
    direction); base frame, mm."""

    chain_deg: tuple[float, ...]
    frames: Mat

    @property
    def flange(self) -> Mat:
        return self.frames[7]

    @property
    def abb_deg(self) -> list[float]:
        return chain_to_abb(self.chain_deg)

    def tcp(self, tool_z_mm: float) -> Mat:
        """The tool's point ``tool_z_mm`` along the flange's z (a straight tool, as
        ``tool_pusher``'s ``tframe`` [0, 0, tool_z_mm])."""
        return self.flange[:3, 3] + self.flange[:3, 2] * tool_z_mm


class Arm:
    """One IRB 14000 arm: its shoulder, limits, forward kinematics and Jacobian."""

    def __init__(self, side: str) -> None:
        if side not in SHOULDERS:
            raise ValueError(f"an IRB 14000 arm is 'left' or 'right', got {side!r}")
        self.side = side
        self.base = transform(*SHOULDERS[side])
        self.lower = np.array([LIMITS_DEG[a][0] for a in CHAIN_AXES])
        self.upper = np.array([LIMITS_DEG[a][1] for a in CHAIN_AXES])

    @property
    def shoulder(self) -> Mat:
        """Where axis 1 meets the body (mm)."""
        return self.base[:3, 3]

    def pose(self, chain_deg: Sequence[float]) -> Pose:
        """Forward kinematics: every joint's frame and the flange's."""
        # rz(q) @ origin is the origin with its rows 0 and 1 turned: all seven made at
        # once (the planner asks this at every iteration of its solvers)
        q = np.radians(np.asarray(chain_deg, dtype=np.float64))
        c, s = np.cos(q)[:, None], np.sin(q)[:, None]
        turned = _ORIGIN_STACK.copy()
        turned[:, 0] = c * _ORIGIN_STACK[:, 0] - s * _ORIGIN_STACK[:, 1]
        turned[:, 1] = s * _ORIGIN_STACK[:, 0] + c * _ORIGIN_STACK[:, 1]
        frames = np.empty((8, 4, 4))
        m = self.base
        for k in range(7):
            frames[k] = m
            m = m @ turned[k]
        frames[7] = m
        return Pose(tuple(float(x) for x in chain_deg), frames)

    def pose_abb(self, abb_deg: Sequence[float]) -> Pose:
        """Forward kinematics of ABB-ordered joints (axes 1..6, then 7)."""
        return self.pose(abb_to_chain(abb_deg))

    def jacobian(self, pose: Pose, point: Mat) -> Mat:
        """(6, 7): the velocity of ``point`` (on the flange's body) and the flange's
        angular velocity per joint rate (rad)."""
        z = pose.frames[:7, :3, 2]
        d = point - pose.frames[:7, :3, 3]
        zxd = np.stack([z[:, 1] * d[:, 2] - z[:, 2] * d[:, 1],  # z x d row by row:
                        z[:, 2] * d[:, 0] - z[:, 0] * d[:, 2],  # np.cross costs more
                        z[:, 0] * d[:, 1] - z[:, 1] * d[:, 0]], axis=1)
        return np.vstack([zxd.T, z.T])

    def limit_excess(self, chain_deg: Sequence[float]) -> tuple[int, float] | None:
        """(ABB axis, degrees past its range) of the joint furthest out, or None."""
        q = np.asarray(chain_deg, dtype=np.float64)
        over = np.maximum(self.lower - q, q - self.upper)
        k = int(np.argmax(over))
        return (CHAIN_AXES[k], float(over[k])) if over[k] > 1e-6 else None

    def limit_room(self, chain_deg: Sequence[float]) -> tuple[int, float]:
        """(ABB axis, degrees) of the joint closest to a limit, and how close."""
        q = np.asarray(chain_deg, dtype=np.float64)
        room = np.minimum(q - self.lower, self.upper - q)
        k = int(np.argmin(room))
        return CHAIN_AXES[k], float(room[k])


_ARMS: dict[str, Arm] = {}


def arm(side: str) -> Arm:
    """The (shared, immutable) model of the ``left`` or ``right`` arm."""
    if side not in _ARMS:
        _ARMS[side] = Arm(side)
    return _ARMS[side]
