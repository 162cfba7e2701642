"""The priorities' edges that scripts/mutation.sh found untested (docs/notes/tests.md).

Why: testbed/fleet/priorities.py turns each arm's signals into the keys the allocator
ranks; a mutation run showed changes no test noticed: the checks of ``waited`` and
``features`` (which value is refused, with which message, and the type handed on), the
running statistics before any update and with no spread, and the thrifty priority's
defaults (threshold 0, ``eps`` as configured, alpha's closed range), the ordered
priority's defaults and checks, and the Random baseline's budget, its remote humans, a
fleet with no human and the rate of its first draw.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from testbed.fleet.allocator import Allocator
from testbed.fleet.priorities import (
    OrderedPriority,
    PrioritySignals,
    RandomPriority,
    RunningStats,
    ThriftyPriority,
)

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
    out = prio.scores(signals([1.0, 1.0], [2.0, 6.0]), update=False)  # the novelty's too
    assert out.tolist() == [0.0, 2.0]


def test_thrifty_alpha_is_a_closed_unit_interval() -> None:
    assert ThriftyPriority(2, alpha=0.0).alpha == 0.0
    assert ThriftyPriority(2, alpha=1.0).alpha == 1.0
    with pytest.raises(ValueError, match=r"^alpha must be in \[0, 1\], got 1\.5$"):
        ThriftyPriority(2, alpha=1.5)


def test_ordered_defaults_count_from_t_0_and_keep_every_u_and_r_at_least_0() -> None:
    prio = OrderedPriority("cur", 2)
    keys = prio.keys(PrioritySignals(t=0, violating=np.array([True, False]),
                                     uncertainty=[0.5, 0.25], risk=[0.75, 0.125]))
    assert keys.tolist() == [[1.0, 0.5, 0.75], [0.0, 0.25, 0.125]]
    assert prio.reads == frozenset({"uncertainty", "risk"})
    assert OrderedPriority("c", 2).reads == frozenset()


@pytest.mark.parametrize("order", ["", "cX", "cc", "xr"])
def test_ordered_refuses_an_order_that_is_not_distinct_letters_of_cur(order: str) -> None:
    with pytest.raises(ValueError, match=re.escape(
            f"order must be distinct letters of 'cur', got {order!r}")):
        OrderedPriority(order, 2)


def test_ordered_refuses_a_negative_initial_period_by_name() -> None:
    with pytest.raises(ValueError, match=r"^initial_period must be >= 0, got -1$"):
        OrderedPriority("c", 2, initial_period=-1)


def test_a_signal_is_float64_and_a_non_numeric_one_is_named() -> None:
    s = PrioritySignals(t=0, violating=VIOL, risk=[1, 2])
    got = s.signal("risk", 2)
    assert got.dtype == np.float64 and got.tolist() == [1.0, 2.0]
    with pytest.raises(ValueError, match=r"^signals\.risk must be numeric: "):
        PrioritySignals(t=0, violating=VIOL, risk=["a", "b"]).signal("risk", 2)


def test_random_budget_is_a_closed_unit_interval() -> None:
    assert RandomPriority(2, 1, budget=1.0).budget == 1.0
    with pytest.raises(ValueError, match=r"^budget must be in \[0, 1\], got 1\.5$"):
        RandomPriority(2, 1, budget=1.5)


def test_random_says_how_its_allocator_got_out_of_step() -> None:
    alloc = Allocator(2, 1, 1, 1, seed=0)
    prio = RandomPriority(2, 1, budget=0.5, seed=0, allocator=alloc)
    alloc.step(np.zeros(2), np.zeros(2, dtype=bool))
    want = ("RandomPriority: its allocator has stepped 1 times but keys() ran 0 times; "
            "allocate with the algorithm's own allocator (Algorithm.allocator or "
            "Algorithm.step), once per keys() call, or the human-effort budget cannot "
            "be kept")
    with pytest.raises(RuntimeError, match=f"^{re.escape(want)}$"):
        prio.keys(PrioritySignals(t=0, violating=np.zeros(2, dtype=bool)))


def test_random_with_no_human_makes_no_arm_eligible() -> None:
    prio = RandomPriority(3, 0, budget=0.5, seed=0)
    keys = prio.keys(PrioritySignals(t=0, violating=np.array([True, False, False])))
    assert keys.tolist() == [[0.0, 0.0]] * 3
    assert prio.effort == 0


def test_random_with_only_remote_humans_makes_no_violating_arm_eligible() -> None:
    for seed in range(20):
        alloc = Allocator(2, 2, 1, 1, seed=seed, on_site=np.array([False, False]))
        prio = RandomPriority(2, 2, budget=1.0, seed=seed, allocator=alloc)
        keys = prio.keys(PrioritySignals(t=0, violating=np.array([True, True])))
        assert keys.tolist() == [[0.0, 0.0], [0.0, 0.0]], seed


def test_random_first_step_draws_busy_humans_at_the_budget_rate() -> None:
    """Step 1: deficit = budget * M, so p = budget; busy ~ Binomial(M, budget): with M = 4
    and budget 0.25, one arm eligible on average (4 every time if p were deficit * M)."""
    chosen = []
    for seed in range(200):
        prio = RandomPriority(4, 4, budget=0.25, seed=seed)
        keys = prio.keys(PrioritySignals(t=0, violating=np.zeros(4, dtype=bool)))
        x = keys[:, 1][keys[:, 1] > 0]
        assert ((x > 0.0) & (x <= 1.0)).all(), keys  # x in (0, 1]
        chosen.append(x.size)
    assert 0.7 <= float(np.mean(chosen)) <= 1.3, np.mean(chosen)
