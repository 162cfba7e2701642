"""The scripted supervisor: its choices on constructed states, and its measured quality."""

from __future__ import annotations

import math

import numpy as np

from sim_twin import TwinCell
from sim_twin.geometry import depth_inside, push_direction
from sim_twin.supervisor import (
    NOMINAL_STEP,
    SAFETY_MARGIN,
    PolicyReport,
    expert_face,
    expert_policy,
    measure,
    random_policy,
)


def test_expert_heads_for_the_goal() -> None:
    assert expert_face((0.5, 0.5), 0.0, (0.5, 0.2)) == 0
    assert expert_face((0.5, 0.5), 0.0, (0.2, 0.5)) == 1
    assert expert_face((0.5, 0.5), 0.0, (0.5, 0.8)) == 2
    assert expert_face((0.5, 0.5), 0.0, (0.8, 0.5)) == 3
    # Turned cube: face 3 of a cube at +40 degrees pushes down-right.
    assert expert_face((0.5, 0.5), math.radians(40), (0.7, 0.67)) == 3


def test_expert_never_plans_a_push_out_of_the_workspace() -> None:
    rng = np.random.default_rng(0)
    for _ in range(2000):
        xy = rng.uniform(0.1, 0.9, 2)
        if depth_inside(xy) < SAFETY_MARGIN:
            continue
        yaw = rng.uniform(-math.pi / 4, math.pi / 4)
        goal = rng.uniform(-0.5, 1.5, 2)  # even a goal outside the workspace
        k = expert_face(xy, yaw, goal)
        end = xy + NOMINAL_STEP * push_direction(k, yaw)
        safe = [depth_inside(xy + NOMINAL_STEP * push_direction(j, yaw)) >= SAFETY_MARGIN
                for j in range(4)]
        assert depth_inside(end) >= SAFETY_MARGIN or not any(safe)


def test_expert_is_a_good_teleoperator() -> None:
    """With every arm teleoperated by the expert: few violations, many successes, far
    above a random pusher (figures in docs/notes/sim_twin.md)."""
    def total(policy_for_seed: object, seeds: range, steps: int) -> PolicyReport:
        reports = []
        for seed in seeds:
            with TwinCell(seed) as cell:
                policy = expert_policy if policy_for_seed is None else random_policy(seed)
                reports.append(measure(cell, policy, steps))
        return PolicyReport(*(sum(getattr(r, f) for r in reports)
                              for f in ("pushes", "successes", "violations", "soft_resets")))

    expert = total(None, range(100, 103), 100)
    rand = total("random", range(100, 103), 100)
    assert expert.pushes == 600
    assert expert.violations_per_100 < 2.0
    assert expert.successes_per_100 >= 15.0
    assert expert.successes_per_100 >= 5 * max(rand.successes_per_100, 1.0)
    assert rand.violations_per_100 > expert.violations_per_100
