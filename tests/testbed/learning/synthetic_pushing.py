"""A tiny drawn pushing world for the learning tests, independent of the PyBullet twin.

Why: the learner's tests must not wait for (or break with) sim_twin, yet they need
images where the labels depend on what the image shows, as in the twin: a red cube and a
green goal on a grey table, pushes that move the cube one step along a face direction,
a violation when the cube leaves the workspace square, a success when it lands on the goal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.core.types import FACE_DIRECTIONS, SUCCESS_RADIUS

LO, HI = 0.075, 0.925  # the workspace square (the twin cuts two corners; not needed here)
STEP = 0.1
CUBE_HALF_PX = 4
GOAL_RADIUS_PX = 3
TABLE = (120, 120, 120)
CUBE = (210, 40, 40)
GOAL = (40, 190, 60)
DIRS = np.asarray(FACE_DIRECTIONS)


def render(cube: np.ndarray, goal: np.ndarray, table: tuple[int, int, int] = TABLE
           ) -> np.ndarray:
    """uint8 (N, 64, 64, 3) images of cubes (N, 2) and goals (N, 2) in [0, 1]^2."""
    n = cube.shape[0]
    out = np.empty((n, 64, 64, 3), dtype=np.uint8)
    out[:] = np.asarray(table, dtype=np.uint8)
    yy, xx = np.mgrid[0:64, 0:64]
    for i in range(n):
        gx, gy = goal[i] * 64
        out[i][(xx - gx) ** 2 + (yy - gy) ** 2 <= GOAL_RADIUS_PX**2] = GOAL
        cx, cy = np.clip(np.round(cube[i] * 64).astype(int), -8, 72)
        y0, y1 = max(cy - CUBE_HALF_PX, 0), min(cy + CUBE_HALF_PX, 64)
        x0, x1 = max(cx - CUBE_HALF_PX, 0), min(cx + CUBE_HALF_PX, 64)
        if y0 < y1 and x0 < x1:
            out[i, y0:y1, x0:x1] = CUBE
    return out


def expert(cube: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Push along the axis with the larger distance to the goal."""
    d = goal - cube
    horizontal = np.abs(d[:, 0]) >= np.abs(d[:, 1])
    return np.where(horizontal, np.where(d[:, 0] < 0, 1, 3), np.where(d[:, 1] < 0, 0, 2))


@dataclass
class Batch:
    images: np.ndarray
    actions: np.ndarray
    next_images: np.ndarray
    violation: np.ndarray
    success: np.ndarray
    cube: np.ndarray
    goal: np.ndarray


def transitions(n: int, rng: np.random.Generator, expert_fraction: float = 0.5,
                goal: tuple[float, float] | None = None) -> Batch:
    """States with the cube anywhere in the workspace and the goal at ``goal`` (default:
    0.05-0.35 from the cube in a random direction); actions from the expert with
    probability ``expert_fraction``, else uniform."""
    cube = rng.uniform(LO, HI, (n, 2))
    if goal is None:
        angle = rng.uniform(0, 2 * np.pi, n)
        radius = rng.uniform(0.05, 0.35, n)
        offset = radius[:, None] * np.stack([np.cos(angle), np.sin(angle)], 1)
        goals = np.clip(cube + offset, LO + 0.03, HI - 0.03)
    else:
        goals = np.tile(np.asarray(goal, dtype=float), (n, 1))
    actions = np.where(rng.random(n) < expert_fraction, expert(cube, goals),
                       rng.integers(0, 4, n))
    nxt = cube + STEP * DIRS[actions] + rng.normal(0, 0.01, (n, 2))
    violation = ((nxt < LO) | (nxt > HI)).any(axis=1)
    success = ~violation & (np.linalg.norm(nxt - goals, axis=1) < SUCCESS_RADIUS)
    return Batch(render(cube, goals), actions.astype(np.int64), render(nxt, goals),
                 violation, success, cube, goals)


def roc_auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """Probability that a positive scores above a negative (ties count half)."""
    pos, neg = scores[labels], scores[~labels]
    if len(pos) == 0 or len(neg) == 0:
        raise ValueError("AUC needs both classes")
    greater = (pos[:, None] > neg[None, :]).mean()
    ties = (pos[:, None] == neg[None, :]).mean()
    return float(greater + 0.5 * ties)
