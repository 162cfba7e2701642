"""The driver's forward kinematics and Jacobian against their definitions.

``drivers/yumi/irb14000.py`` makes a pose's frames with every joint's turned origin at
once, and the Jacobian's cross products row by row (the planner asks both at every
iteration of its solvers): held here to the chain of products they stand for, written
out, and to central differences of the point they move."""

from __future__ import annotations

import math

import numpy as np

from drivers.yumi.irb14000 import JOINT_ORIGINS, arm, transform


def _chain(side: str, chain_deg: np.ndarray) -> np.ndarray:
    """base @ rot_z(q1) @ origin1 @ rot_z(q2) @ origin2 ..., each joint's frame before
    its turn, the flange last."""
    m = arm(side).base
    frames = []
    for q, origin in zip(chain_deg, JOINT_ORIGINS, strict=True):
        frames.append(m)
        c, s = math.cos(math.radians(q)), math.sin(math.radians(q))
        rz = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], float)
        m = m @ rz @ transform(*origin)
    return np.stack([*frames, m])


def test_a_poses_frames_are_the_chain_of_products() -> None:
    rng = np.random.default_rng(3)
    for side in ("left", "right"):
        for q in rng.uniform(-170.0, 170.0, (100, 7)):
            pose = arm(side).pose(q)
            assert pose.chain_deg == tuple(float(x) for x in q)
            assert np.allclose(pose.frames, _chain(side, q), rtol=0, atol=1e-9)


def test_the_jacobian_is_the_points_and_the_flanges_motion_per_joint() -> None:
    rng = np.random.default_rng(4)
    model = arm("left")
    h = 1e-6
    for q in rng.uniform(-120.0, 120.0, (20, 7)):
        pose = model.pose(q)
        point = pose.tcp(184.2)
        jac = model.jacobian(pose, point)
        for k in range(7):
            up, down = q.copy(), q.copy()
            up[k] += math.degrees(h)
            down[k] -= math.degrees(h)
            moved = (model.pose(up).tcp(184.2) - model.pose(down).tcp(184.2)) / (2 * h)
            assert np.allclose(jac[:3, k], moved, atol=1e-4 * (1 + np.abs(moved).max()))
            assert np.allclose(jac[3:, k], pose.frames[k][:3, 2], atol=1e-12)
