"""The advantage's check against the twin's truth (issue 46, item 1) can tell right from
wrong: on real twin states and real PyBullet pushes, an advantage that IS the truth scores
AUROC 1 (pooled and within states), its negation 0, one that ignores the state about
0.5; and a state put back twice pushes the same again, up to the push's own jitter (the
truth is reproducible).

The real learner's figure comes from a trained critic: tests/testbed/learning/
test_critics_on_twin.py, which has one.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import sim_twin.cell as cell_module
from testbed.core.types import NUM_ACTIONS
from testbed.lab.advantage_truth import (
    TRUTH_SEED,
    draw_states,
    judge,
    push_truth,
    truth_of_states,
)


@pytest.fixture(scope="module")
def drawn() -> tuple[list, np.ndarray]:  # type: ignore[type-arg]
    with cell_module.TwinCell(seed=TRUTH_SEED) as cell:
        states = draw_states(cell, 24, np.random.default_rng(0))
        return states, truth_of_states(cell, states)


def _oracle(states: list, truth: np.ndarray, sign: float, policy: np.ndarray):  # type: ignore[no-untyped-def,type-arg]
    """A value function that looks the truth up by image (the test's, not the product's)."""
    keys = {s.image.tobytes(): i for i, s in enumerate(states)}
    finite = np.clip(truth, -2.0, 2.0)

    def value(images: np.ndarray, actions: np.ndarray) -> SimpleNamespace:
        rows = np.asarray([keys[x.tobytes()] for x in images])
        q = sign * finite[rows, actions]
        return SimpleNamespace(advantage=q - sign * finite[rows, policy[rows]],
                               policy_action=policy[rows])
    return value


def test_the_check_scores_the_truth_one_its_negation_zero(drawn) -> None:  # type: ignore[no-untyped-def]
    states, truth = drawn
    assert truth.shape == (24, NUM_ACTIONS) and np.isfinite(truth).any()
    face0 = np.zeros(24, np.int64)  # a policy that always pushes face 0
    right = judge(states, truth, _oracle(states, truth, 1.0, face0))
    wrong = judge(states, truth, _oracle(states, truth, -1.0, face0))
    assert 10 < right.better < right.pushes == 24 * (NUM_ACTIONS - 1)
    assert right.auroc == 1.0 and right.auroc_low == 1.0
    assert right.within == 1.0 and right.within_low == 1.0
    assert wrong.auroc == 0.0 and wrong.auroc_high == 0.0
    assert wrong.within == 0.0 and wrong.within_high == 0.0
    assert 1 < right.episodes < 24  # consecutive states share goal episodes
    assert right.top_is_expert > 0.5  # the expert's push is usually the best in truth

    def blind(images: np.ndarray, actions: np.ndarray) -> SimpleNamespace:
        return SimpleNamespace(advantage=np.asarray(actions, float) - 1.5,
                               policy_action=np.zeros(len(actions), np.int64))
    chance = judge(states, truth, blind)
    assert 0.2 < chance.auroc < 0.8 and chance.auroc_low < 0.5 < chance.auroc_high
    assert 0.2 < chance.within < 0.8 and chance.within_low < 0.5 < chance.within_high
    assert "AUROC 1.000 [1.000, 1.000], within states 1.000 [1.000, 1.000]" in right.line()


def test_a_state_put_back_pushes_as_the_state_itself(drawn) -> None:  # type: ignore[no-untyped-def]
    states, truth = drawn
    with cell_module.TwinCell(seed=TRUTH_SEED) as cell:
        again = [push_truth(cell, states[0], a) for a in range(NUM_ACTIONS)]
    # the same state and push: the same outcome class and a distance within the jitter
    assert [np.isinf(x) for x in again] == [np.isinf(x) for x in truth[0]]
    finite = np.isfinite(truth[0])
    assert np.allclose(np.asarray(again)[finite], truth[0][finite], atol=0.03)
