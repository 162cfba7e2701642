"""The safety and goal critics rank held-out transitions by what comes next.

Data: the drawn pushing world with the goal at the centre, pushes half by the expert and
half at random, so that both violations (the cube pushed over the workspace's edge) and
successes (pushed onto the goal) occur. The critics train through ``Learner.pretrain``
with the configured discounts (gamma_safe 0.5, gamma_goal 0.999); their scores on held-out
transitions, Q_risk(s, a) and Q_goal(s, a) at the logged action, must give a ROC AUC of at
least 0.8 for "violation at the next step" and "success at the next step".

The goal stays at the centre here so that this test stays fast; goals anywhere, as in
a trial, are the twin test's (``test_critics_on_twin.py``), where the goal critic needs
~600 steps (docs/notes/learning.md).
"""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_pushing import Batch, roc_auc, transitions

from testbed.learning import Learner, Transitions
from testbed.learning.learning_config import LearningConfig

pytestmark = pytest.mark.slow  # it trains networks: out of the fast tier

CFG = LearningConfig(ensemble_size=2, batch_size=64, lr=1e-3)
STEPS = 100
GOAL = (0.5, 0.5)


def as_transitions(b: Batch) -> Transitions:
    return Transitions.build(b.images, b.actions, b.next_images, b.violation, b.success)


@pytest.fixture(scope="module")
def trained() -> tuple[Learner, Batch]:
    rng = np.random.default_rng(0)
    train = transitions(3000, rng, goal=GOAL)
    held_out = transitions(600, rng, goal=GOAL)
    assert train.violation.sum() > 100 and train.success.sum() > 100
    learner = Learner(CFG, seed=0)
    learner.pretrain(transitions=as_transitions(train), steps=STEPS)
    return learner, held_out


def test_safety_critic_predicts_violations(trained: tuple[Learner, Batch]) -> None:
    learner, held = trained
    scores = learner.critic_values(held.images, held.actions)["risk"]
    auc = roc_auc(scores, held.violation)
    assert auc >= 0.8, auc
    assert scores[held.violation].mean() > scores[~held.violation].mean() + 0.3


def test_goal_critic_predicts_successes(trained: tuple[Learner, Batch]) -> None:
    learner, held = trained
    goal_risk = learner.critic_values(held.images, held.actions)["goal_risk"]
    auc = roc_auc(-goal_risk, held.success)
    assert auc >= 0.8, auc


def test_act_reports_risk_of_the_policy_action(trained: tuple[Learner, Batch]) -> None:
    learner, held = trained
    out = learner.act(held.images[:50])
    at_pi = learner.critic_values(held.images[:50], out.actions)
    assert np.array_equal(out.risk, at_pi["risk"])
    assert np.array_equal(out.goal_risk, at_pi["goal_risk"])
