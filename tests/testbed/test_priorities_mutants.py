"""The priorities' edges that scripts/mutation.sh found untested (docs/notes/tests.md).

Why: testbed/fleet/priorities.py turns each arm's signals into the keys the allocator
ranks; a mutation run showed changes no test noticed: the checks of ``waited`` and
``features`` (which value is refused, with which message, and the type handed on), the
running statistics before any update and with no spread, and the thrifty priority's
defaults (threshold 0, ``eps`` as configured, alpha's closed range).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from testbed.fleet.priorities import PrioritySignals, RunningStats, ThriftyPriority

VIOL = np.array([False, False])


def test_waited_is_zeros_when_unknown_and_int64_when_given() -> None:
    none = PrioritySignals(t=0, violating=VIOL).waited_array(2)
    assert none.dtype == np.int64 and none.tolist() == [0, 0]
    given = PrioritySignals(t=0, violating=VIOL,
                            waited=np.array([0, 3], dtype=np.int32)).waited_array(2)
    assert given.dtype == np.int64 and given.tolist() == [0, 3]


@pytest.mark.parametrize("waited", [
    np.array([1, 2, 3]),            # wrong shape, ints >= 0
    np.array([1.0, 2.0]),           # right shape, floats >= 0
    np.array([1, -1]),              # right shape, ints, one negative
])
def test_waited_refuses_a_wrong_shape_a_float_or_a_negative(waited: np.ndarray) -> None:
    want = (f"signals.waited must be ints >= 0 with shape (2,), "
            f"got {waited.dtype} {waited.shape}")
    with pytest.raises(ValueError, match=f"^{re.escape(want)}$"):
        PrioritySignals(t=0, violating=VIOL, waited=waited).waited_array(2)


def test_features_are_float64_and_checked_with_their_messages() -> None:
    ints = PrioritySignals(t=0, violating=VIOL, features=[[1, 2], [3, 4]]).features_array(2)
    assert ints.dtype == np.float64 and ints.tolist() == [[1.0, 2.0], [3.0, 4.0]]
    with pytest.raises(ValueError, match=r"^signals\.features is required by this "
                                         r"priority function$"):
        PrioritySignals(t=0, violating=VIOL).features_array(2)
    with pytest.raises(ValueError, match=re.escape("must have shape (2, D), got (2,)")):
        PrioritySignals(t=0, violating=VIOL, features=[1.0, 2.0]).features_array(2)
    with pytest.raises(ValueError, match=re.escape("must have shape (2, D), got (3, 1)")):
        PrioritySignals(t=0, violating=VIOL, features=[[1.0], [2.0], [3.0]]).features_array(2)
    with pytest.raises(ValueError, match=r"^signals\.features has NaN$"):
        PrioritySignals(t=0, violating=VIOL,
                        features=[[1.0], [np.nan]]).features_array(2)


def test_running_stats_start_at_zero_and_divide_by_eps_without_spread() -> None:
    fresh = RunningStats()
    assert fresh.state_dict() == {"count": 0, "mean": 0.0, "m2": 0.0}
    flat = RunningStats()
    flat.update(np.array([3.0, 3.0, 3.0]))
    assert flat.std == 0.0
    # no spread: (v - mean) / eps, the sign of the difference kept
    assert flat.standardise(np.array([4.0, 2.0])).tolist() == [1e8, -1e8]
    spread = RunningStats()
    spread.update(np.array([1.0, 3.0]))
    assert spread.standardise(np.array([5.0]))[0] == pytest.approx(3.0, rel=1e-7)


def signals(risk: list[float], novelty: list[float]) -> PrioritySignals:
    return PrioritySignals(t=0, violating=VIOL, goal_risk=risk, novelty=novelty)


def test_thrifty_default_threshold_is_zero() -> None:
    # z-scores of [0, 1] are [-1, 1] (up to eps); with alpha 0.5 the score is [-1, 1]
    keys = ThriftyPriority(2).keys(signals([0.0, 1.0], [0.0, 1.0]))
    assert keys[0].tolist() == [0.0, 0.0]
    assert keys[1, 0] == pytest.approx(1.0, rel=1e-6)


def test_thrifty_uses_its_own_eps() -> None:
    # no spread in either signal: the score is 0 / eps, and with a value away from the
    # mean, (v - mean) / eps: eps = 1 keeps it at the difference itself
    prio = ThriftyPriority(2, alpha=0.5, eps=1.0)
    prio.scores(signals([1.0, 1.0], [2.0, 2.0]))
    out = prio.scores(signals([1.0, 3.0], [2.0, 2.0]), update=False)
    assert out.tolist() == [0.0, 1.0]


def test_thrifty_alpha_is_a_closed_unit_interval() -> None:
    assert ThriftyPriority(2, alpha=0.0).alpha == 0.0
    assert ThriftyPriority(2, alpha=1.0).alpha == 1.0
    with pytest.raises(ValueError, match=r"^alpha must be in \[0, 1\], got 1\.5$"):
        ThriftyPriority(2, alpha=1.5)
