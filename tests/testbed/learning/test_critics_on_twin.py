"""The critics on held-out transitions of the PyBullet twin (the issue's acceptance test).

Transitions come from the twin as a trial makes them: each arm's goal is the twin's own
(a new one anywhere in the workspace after every success, as in a trial), the cube moves
only by pushes, and a violation is followed by a hard reset. To meet enough violations,
before a step each arm's cube is, with probability 0.4, put somewhere else in the
workspace at any yaw (its goal kept). Pushes are the scripted expert's or random, half
each. Violation and success are the twin's own judgement.

The learner first learns a BC policy from the expert's labels of 500 of the training
states (the critics estimate Q of that policy, as in a trial), then the critics train
on 3000 transitions with the configured discounts (gamma_safe 0.5, gamma_goal 0.999)
and must rank 800 held-out transitions from another cell by "violation at the next
step" (Q_risk(s, a)) and "success at the next step" (Q_goal(s, a)) with a ROC AUC of at
least 0.8.

Why 600 critic steps: with the goal anywhere, success depends on where the goal is
relative to the cube, and the goal critic's gamma of 0.999 bootstraps through a target
network that follows at tau 0.005 (a time constant of 200 steps). Measured on this data
(batch 64, 2 members): AUC 0.64-0.84 after 300 steps, 0.87-0.94 after 600, 0.88-0.92 up
to 1600 (docs/notes/learning.md). About a minute on 2 cores.

Skipped when the twin cannot be imported (no pybullet on this machine).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from synthetic_pushing import roc_auc

import sim_twin.cell as cell_module
import sim_twin.geometry as geometry
from testbed.learning import Learner, Transitions
from testbed.learning.learning_config import LearningConfig

CFG = LearningConfig(ensemble_size=2, batch_size=64, lr=1e-3, augmentation_factor=2)
POLICY_STEPS = 100
CRITIC_STEPS = 600
P_EXPERT = 0.5
P_MOVE = 0.4


def collect(cell: Any, n: int, rng: np.random.Generator
            ) -> tuple[Transitions, npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    """``n`` transitions, the expert's label of each state, and each state's goal."""
    images, actions, next_images, violation, success = [], [], [], [], []
    expert, goals = [], []
    arms = cell.arm_names
    while len(actions) < n:
        for arm in arms:
            if rng.random() < P_MOVE:
                xy = rng.uniform(0.05, 0.95, 2)
                while geometry.depth_inside(xy) < 0.01:
                    xy = rng.uniform(0.05, 0.95, 2)
                cell.set_arm_state(arm, xy, rng.uniform(-np.pi / 4, np.pi / 4),
                                   cell.arm_state(arm).goal_xy)
        before = cell.observe()
        labels = {a: cell.expert_action(a) for a in arms}
        state_goals = {a: cell.arm_state(a).goal_xy for a in arms}
        faces = {a: labels[a] if rng.random() < P_EXPERT else int(rng.integers(4))
                 for a in arms}
        outcome = cell.push(faces)
        after = cell.observe()
        for arm in arms:
            images.append(before[arm])
            actions.append(faces[arm])
            next_images.append(after[arm])
            violation.append(outcome[arm].violation)
            success.append(outcome[arm].success)
            expert.append(labels[arm])
            goals.append(state_goals[arm])
            if outcome[arm].violation:
                cell.hard_reset(arm)
    data = Transitions.build(np.stack(images), np.asarray(actions), np.stack(next_images),
                             np.asarray(violation), np.asarray(success))
    return data, np.asarray(expert, np.int64), np.asarray(goals)


# The module's fixture trains for ~150 s on a quiet 2-core machine; under load (another
# trial beside the suite) it passed 300 s, the suite's default limit.
pytestmark = [pytest.mark.timeout(900), pytest.mark.slow]


@pytest.fixture(scope="module")
def trained() -> tuple[Learner, Transitions, npt.NDArray[np.float64]]:
    with cell_module.TwinCell(seed=1) as cell:
        train, expert, _ = collect(cell, 3000, np.random.default_rng(1))
    with cell_module.TwinCell(seed=2) as cell:
        held, _, held_goals = collect(cell, 800, np.random.default_rng(2))
    assert train.violation.sum() > 80 and train.success.sum() > 150
    assert held.violation.sum() > 25 and held.success.sum() > 40
    learner = Learner(CFG, seed=0)
    learner.pretrain(train.images[:500], expert[:500], steps=POLICY_STEPS)
    learner.pretrain(transitions=train, steps=CRITIC_STEPS,
                     critics=["safety", "goal", "value"])  # value: issue 46's advantage
    return learner, held, held_goals


def test_goals_cover_the_workspace(
        trained: tuple[Learner, Transitions, npt.NDArray[np.float64]]) -> None:
    """The test is about goals anywhere: the held-out goals spread over the workspace."""
    _, held, goals = trained
    assert len(goals) == len(held.actions)
    assert (goals.std(axis=0) > 0.15).all()
    assert (goals.min(axis=0) < 0.3).all() and (goals.max(axis=0) > 0.7).all()
    successes = goals[held.success]
    assert len(np.unique(np.round(successes, 3), axis=0)) > 20


def test_safety_critic_auc_on_twin(
        trained: tuple[Learner, Transitions, npt.NDArray[np.float64]]) -> None:
    learner, held, _ = trained
    risk = learner.critic_values(held.images, held.actions)["risk"]
    assert roc_auc(risk, held.violation) >= 0.8


def test_goal_critic_auc_on_twin(
        trained: tuple[Learner, Transitions, npt.NDArray[np.float64]]) -> None:
    learner, held, _ = trained
    goal_risk = learner.critic_values(held.images, held.actions)["goal_risk"]
    auc = roc_auc(-goal_risk, held.success)
    print(f"goal critic AUC {auc:.3f}")
    assert auc >= 0.85  # issue 12, item 7: goals anywhere in the workspace


def test_the_advantage_ranks_pushes_as_the_twin_does(
        trained: tuple[Learner, Transitions, npt.NDArray[np.float64]]) -> None:
    """Issue 46, item 1: on states of a cell no training or tuning saw, this learner's
    value critic ranks a push that ends better in the twin than the policy's own above
    one that does not, the check's 95 % lower bound (goal episodes resampled) above 0.65
    (testbed/lab/advantage_truth.py; the check's power: tests/testbed/
    test_advantage_truth.py). One learner (seed 0): across learner seeds the figure
    varies widely (docs/notes/learning.md, "The value of every push"); the goal
    critic's figure on the same states is printed beside it, not compared."""
    from testbed.lab.advantage_truth import (
        TRUTH_SEED,
        draw_states,
        judge,
        truth_of_states,
    )
    from testbed.learning.advantage import push_values

    learner, _, _ = trained
    with cell_module.TwinCell(seed=TRUTH_SEED) as cell:
        states = draw_states(cell, 200, np.random.default_rng(TRUTH_SEED))
        truth = truth_of_states(cell, states)
    got = judge(states, truth, learner.push_values)

    def by_goal_critic(images: np.ndarray, actions: np.ndarray) -> Any:
        import torch

        return push_values(learner.policy, learner.goal.net, "min", torch.from_numpy(images),
                           torch.from_numpy(actions), learner.device)

    goal = judge(states, truth, by_goal_critic)  # beside it: the seed's goal critic
    print(f"value critic: {got.line()}\ngoal critic: {goal.line()}")
    assert got.auroc_low > 0.65 and got.within_low > 0.65, got.line()
