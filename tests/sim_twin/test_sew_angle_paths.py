"""The twin's arm angle of one pose (plain floats) against its batch (numpy) path.

``sim_twin/sew_angle.py`` computes one pose's arm angle and gradient on plain floats
(the inverse kinematics' every iteration) and many poses' with numpy: the same formulas
twice, so they are held together here, and the one-pose gradient against central
differences of the angle itself."""

from __future__ import annotations

import math

import numpy as np

from sim_twin.sew_angle import arm_angle_batch
from sim_twin.yumi_arms import ArmModel


def _wrapped(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def test_one_pose_and_a_batch_give_the_same_angle_and_gradient() -> None:
    rng = np.random.default_rng(7)
    for side in ("left", "right"):
        model = ArmModel(side)
        qs = rng.uniform(-160.0, 160.0, (200, 7))
        frames = np.stack([model.pose(q).frames for q in qs])
        batch_psi, batch_grad = arm_angle_batch(frames)
        for k in range(len(qs)):
            psi, grad = arm_angle_batch(frames[k:k + 1])
            assert psi.shape == (1,) and grad.shape == (1, 7)
            assert abs(_wrapped(float(psi[0] - batch_psi[k]))) < 1e-12
            assert np.allclose(grad[0], batch_grad[k], rtol=1e-9, atol=1e-12)


def test_the_one_pose_gradient_is_the_angles_derivative() -> None:
    rng = np.random.default_rng(8)
    model = ArmModel("left")
    h = 1e-6
    for q in rng.uniform(-120.0, 120.0, (30, 7)):
        _, grad = arm_angle_batch(model.pose(q).frames[None])
        for j in range(7):
            up, down = q.copy(), q.copy()
            up[j] += math.degrees(h)
            down[j] -= math.degrees(h)
            a = arm_angle_batch(model.pose(up).frames[None])[0][0]
            b = arm_angle_batch(model.pose(down).frames[None])[0][0]
            assert abs(_wrapped(a - b) / (2 * h) - grad[0, j]) < 1e-4 * (1 + abs(grad[0, j]))
