"""The critics on held-out transitions of the PyBullet twin (the issue's acceptance test).

Transitions: a twin cell's two arms, each placed (``set_arm_state``) with the cube
anywhere inside the workspace at any yaw and the goal at the centre, pushed by the
scripted expert or at random (half each), with the twin's own physics and judgement of
violation and success. The critics train on 3000 such transitions with the configured
discounts and must rank 600 held-out ones by "violation at the next step" and "success at
the next step" with a ROC AUC of at least 0.8.

Skipped when the twin cannot be imported (no pybullet on this machine).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from synthetic_pushing import roc_auc

from testbed.config import LearningConfig
from testbed.learning import Learner, Transitions

cell_module = pytest.importorskip("sim_twin.cell")
geometry = pytest.importorskip("sim_twin.geometry")

CFG = LearningConfig(ensemble_size=2, batch_size=64, lr=1e-3)
STEPS = 100
GOAL = (0.5, 0.5)


def collect(cell: Any, n: int, rng: np.random.Generator) -> Transitions:
    images, actions, next_images, violation, success = [], [], [], [], []
    arms = cell.arm_names
    while len(actions) < n:
        for arm in arms:
            xy = rng.uniform(0.05, 0.95, 2)
            while geometry.depth_inside(xy) < 0.01:
                xy = rng.uniform(0.05, 0.95, 2)
            cell.set_arm_state(arm, xy, rng.uniform(-np.pi / 4, np.pi / 4), GOAL)
        before = cell.observe()
        faces = {a: cell.expert_action(a) if rng.random() < 0.5 else int(rng.integers(4))
                 for a in arms}
        outcome = cell.push(faces)
        after = cell.observe()
        for arm in arms:
            images.append(before[arm])
            actions.append(faces[arm])
            next_images.append(after[arm])
            violation.append(outcome[arm].violation)
            success.append(outcome[arm].success)
    return Transitions.build(np.stack(images), np.asarray(actions), np.stack(next_images),
                             np.asarray(violation), np.asarray(success))


@pytest.fixture(scope="module")
def trained() -> tuple[Learner, Transitions]:
    rng = np.random.default_rng(0)
    with cell_module.TwinCell(seed=0) as cell:
        train = collect(cell, 3000, rng)
        held = collect(cell, 600, rng)
    assert train.violation.sum() > 100 and train.success.sum() > 100
    assert held.violation.sum() > 20 and held.success.sum() > 20
    learner = Learner(CFG, seed=0)
    learner.pretrain(transitions=train, steps=STEPS)
    return learner, held


def test_safety_critic_auc_on_twin(trained: tuple[Learner, Transitions]) -> None:
    learner, held = trained
    risk = learner.critic_values(held.images, held.actions)["risk"]
    assert roc_auc(risk, held.violation) >= 0.8


def test_goal_critic_auc_on_twin(trained: tuple[Learner, Transitions]) -> None:
    learner, held = trained
    goal_risk = learner.critic_values(held.images, held.actions)["goal_risk"]
    assert roc_auc(-goal_risk, held.success) >= 0.8
