"""The scripted supervisor: the "algorithmic human" that teleoperates twin arms.

Why a model and not a search in the physics: the expert's choice is asked for every
arm at every timestep (the twin host reports it with each observation), for fleets of
up to 100 arms, and must not disturb the world it looks at. So it plans on the ground
truth state with a one-push model -- face ``k`` moves the cube ``NOMINAL_STEP`` along
its face direction -- and picks, among the pushes whose predicted end stays at least
``SAFETY_MARGIN`` inside the workspace, the one that ends nearest the goal. If no push
is safe it takes the one that ends deepest inside. The measured quality of this expert
is in docs/notes/sim_twin.md (and asserted by tests/sim_twin).

The hard-reset half of the supervisor is ``TwinCell.hard_reset`` (the cube back near
the centre); ``measure`` runs a cell under any policy with immediate hard resets. The
cell is typed by :class:`SupervisedCell`, the few calls used here, so this module needs
nothing of ``sim_twin.cell`` (which imports it for ``expert_face``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from sim_twin.constants import NUM_ACTIONS
from sim_twin.geometry import depth_inside, push_direction

NOMINAL_STEP = 0.106
"""Mean canonical displacement of one push (measured: 34 mm on a 320 mm workspace)."""
SAFETY_MARGIN = 0.03
"""Predicted ends closer than this to the workspace edge count as unsafe (covers the
spread of real pushes: length +-10 %, turn of a few degrees)."""


def expert_face(cube_xy: Sequence[float], yaw: float, goal_xy: Sequence[float],
                step: float = NOMINAL_STEP, margin: float = SAFETY_MARGIN) -> int:
    """The face push that best brings the cube to its goal without leaving the workspace."""
    xy = np.asarray(cube_xy, dtype=np.float64)
    ends = np.stack([xy + step * push_direction(k, yaw) for k in range(NUM_ACTIONS)])
    depth = depth_inside(ends)
    dist = np.linalg.norm(ends - np.asarray(goal_xy, dtype=np.float64), axis=1)
    safe = depth >= margin
    if safe.any():
        return int(np.argmin(np.where(safe, dist, math.inf)))
    return int(np.argmax(depth))


class PushOutcome(Protocol):
    """What ``measure`` reads of one arm's push (``sim_twin.cell.TwinOutcome``)."""

    @property
    def success(self) -> bool: ...
    @property
    def violation(self) -> bool: ...
    @property
    def soft_reset(self) -> bool: ...


class SupervisedCell(Protocol):
    """The calls of a cell this module makes (``sim_twin.cell.TwinCell`` has them)."""

    arm_names: tuple[str, ...]

    def push(self, faces: Mapping[str, int]) -> Mapping[str, PushOutcome]: ...
    def hard_reset(self, arm: str) -> None: ...
    def expert_action(self, arm: str) -> int: ...


Policy = Callable[[SupervisedCell, str], int]


def expert_policy(cell: SupervisedCell, arm: str) -> int:
    return cell.expert_action(arm)


def random_policy(seed: int) -> Policy:
    """A uniformly random pusher (the baseline the expert is compared against)."""
    rng = np.random.default_rng(seed)
    return lambda _cell, _arm: int(rng.integers(NUM_ACTIONS))


@dataclass(frozen=True, slots=True)
class PolicyReport:
    pushes: int
    successes: int
    violations: int
    soft_resets: int

    @property
    def successes_per_100(self) -> float:
        return 100.0 * self.successes / max(self.pushes, 1)

    @property
    def violations_per_100(self) -> float:
        return 100.0 * self.violations / max(self.pushes, 1)


def measure(cell: SupervisedCell, policy: Policy, timesteps: int) -> PolicyReport:
    """Every arm of the cell pushes by ``policy`` each timestep; a violating arm is
    hard-reset at once (so every timestep is a push for every arm)."""
    pushes = successes = violations = soft = 0
    for _ in range(timesteps):
        out = cell.push({arm: policy(cell, arm) for arm in cell.arm_names})
        for arm, o in out.items():
            pushes += 1
            successes += o.success
            violations += o.violation
            soft += o.soft_reset and not o.success
            if o.violation:
                cell.hard_reset(arm)
    return PolicyReport(pushes, successes, violations, soft)
