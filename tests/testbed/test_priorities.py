"""Every priority function on hand-built signals, and the algorithm registry."""

from __future__ import annotations

import json

import numpy as np
import pytest

from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import ALGORITHM_NAMES, ALGORITHMS, get_algorithm
from testbed.fleet.priorities import (
    OrderedPriority,
    PriorityFunction,
    PrioritySignals,
    RandomPriority,
    RunningStats,
    ThriftyPriority,
)

PARAMS = AlgorithmConfig(t_T=2, t_R=3, t_I=5, u_hat=0.1, r_hat=0.5, thrifty_alpha=0.25,
                         thrifty_threshold=0.0, random_budget=0.4)

# Four arms: violating, uncertain, risky, calm.
VIOL = np.array([True, False, False, False])
UNC = np.array([0.3, 0.1, 0.0999, 0.0])  # 0.1 is exactly u_hat: kept
RISK = np.array([0.9, 0.2, 0.5, 0.4999])  # 0.5 is exactly r_hat: kept


def signals(t: int, **kw: object) -> PrioritySignals:
    base: dict[str, object] = {"violating": VIOL, "uncertainty": UNC, "risk": RISK,
                               "goal_risk": np.zeros(4), "novelty": np.zeros(4)}
    base.update(kw)
    return PrioritySignals(t=t, **base)  # type: ignore[arg-type]


def keys_of(name: str, t: int, params: AlgorithmConfig = PARAMS, **kw: object) -> np.ndarray:
    alg = get_algorithm(name, params, 4, 2, seed=0)
    return alg.priority.keys(signals(t, **kw))


# --------------------------------------------------------------------------- C.U.R.


def test_cur_during_the_initial_period_penalises_violations() -> None:
    keys = keys_of("cur", t=4)  # t < t_I = 5
    np.testing.assert_array_equal(keys, [[-1.0, 0.3, 0.9],
                                         [0.0, 0.1, 0.0],
                                         [0.0, 0.0, 0.5],
                                         [0.0, 0.0, 0.0]])


def test_cur_after_the_initial_period_prioritises_violations() -> None:
    keys = keys_of("cur", t=5)
    np.testing.assert_array_equal(keys[:, 0], [1.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(keys[:, 1:], keys_of("cur", t=4)[:, 1:])


def test_cur_initial_period_zero_and_cur_i_never_penalise() -> None:
    assert keys_of("cur", t=0, params=PARAMS.model_copy(update={"t_I": 0}))[0, 0] == 1.0
    assert keys_of("cur-i", t=0)[0, 0] == 1.0


def test_cur_allocation_skips_violating_arms_during_the_initial_period() -> None:
    alg = get_algorithm("cur", PARAMS, 4, 4, seed=0)
    assign = alg.step(signals(0))
    assert assign[0] == -1  # key (-1, ...) is not > 0: no human during t_I
    assert (assign[1:3] >= 0).all() and assign[3] == -1
    one = get_algorithm("cur", PARAMS, 4, 1, seed=0)
    history = [one.step(signals(t)).tolist() for t in range(6)]
    # (0, 0.1, 0) > (0, 0, 0.5): arm 1 until t_I, then the violating arm 0 (a reset).
    assert history[:5] == [[-1, 0, -1, -1]] * 5
    assert history[5] == [0, -1, -1, -1] and one.allocator.kinds[0] == "reset"


def test_thresholds_are_inclusive_and_configurable() -> None:
    keys = keys_of("cur", t=9, params=PARAMS.model_copy(update={"u_hat": 0.0, "r_hat": 0.0}))
    np.testing.assert_array_equal(keys[:, 1], UNC)
    np.testing.assert_array_equal(keys[:, 2], RISK)
    keys = keys_of("cur", t=9, params=PARAMS.model_copy(update={"u_hat": 1.0, "r_hat": 1.0}))
    assert not keys[:, 1:].any()


@pytest.mark.parametrize("order", ["c", "u", "r", "cu", "cr", "ur", "uc", "ru", "cru"])
def test_ablations_are_their_entries_in_order_without_initial_period(order: str) -> None:
    keys = keys_of(order, t=0)
    column = {"c": VIOL.astype(float), "u": np.where(UNC >= 0.1, UNC, 0.0),
              "r": np.where(RISK >= 0.5, RISK, 0.0)}
    np.testing.assert_array_equal(keys, np.stack([column[x] for x in order], axis=1))
    assert get_algorithm(order, PARAMS, 4, 2, 0).names == tuple(order)


def test_fleet_ed_is_u_then_c() -> None:
    alg = get_algorithm("fleet-ed", PARAMS, 4, 2, seed=0)
    assert alg.names == ("u", "c")
    np.testing.assert_array_equal(alg.priority.keys(signals(0)),
                                  [[0.3, 1.0], [0.1, 0.0], [0.0, 0.0], [0.0, 0.0]])


def test_bc_resets_only_and_does_not_learn() -> None:
    alg = get_algorithm("bc", PARAMS, 4, 2, seed=0)
    assert (alg.learns, alg.teleop, alg.names) == (False, False, ("c",))
    np.testing.assert_array_equal(alg.priority.keys(signals(0))[:, 0], [1.0, 0.0, 0.0, 0.0])
    rng = np.random.default_rng(0)
    for t in range(200):
        alg.step(signals(t, violating=rng.random(4) < 0.3, uncertainty=rng.random(4),
                         risk=rng.random(4)))
        assert all(k in (None, "reset") for k in alg.allocator.kinds)
    assert all(spec.learns and spec.teleop for name, spec in ALGORITHMS.items() if name != "bc")


# ----------------------------------------------------------------------- Fleet-TD


def test_running_stats_match_numpy_over_batches() -> None:
    rng = np.random.default_rng(1)
    stats, seen = RunningStats(), []
    for size in (1, 5, 0, 17, 3):
        batch = rng.normal(3.0, 2.0, size)
        stats.update(batch)
        seen.extend(batch)
        if seen:
            assert stats.count == len(seen)
            assert stats.mean == pytest.approx(np.mean(seen))
            assert stats.std == pytest.approx(np.std(seen))


def test_thrifty_scores_standardise_with_this_steps_values_included() -> None:
    td = ThriftyPriority(3, alpha=0.25, threshold=0.0)
    assert td.names == ("s", "c")
    s0 = PrioritySignals(t=0, violating=np.array([False, False, True]),
                         goal_risk=np.array([0.0, 1.0, 2.0]), novelty=np.array([5.0, 5.0, 8.0]))
    keys = td.keys(s0)
    zr = (np.array([0.0, 1.0, 2.0]) - 1.0) / (np.std([0, 1, 2]) + 1e-8)
    zn = (np.array([5.0, 5.0, 8.0]) - 6.0) / (np.std([5, 5, 8]) + 1e-8)
    score = 0.25 * zr + 0.75 * zn
    np.testing.assert_allclose(keys[:, 0], np.maximum(score, 0.0))
    np.testing.assert_array_equal(keys[:, 1], [0.0, 0.0, 1.0])
    # The running statistics now hold all six values of the next call too.
    s1 = PrioritySignals(t=1, violating=np.zeros(3, bool), goal_risk=np.array([4.0, 4, 4]),
                         novelty=np.array([5.0, 5, 5]))
    td.keys(s1)
    assert td.risk_stats.mean == pytest.approx(np.mean([0, 1, 2, 4, 4, 4]))
    assert td.novelty_stats.std == pytest.approx(np.std([5, 5, 8, 5, 5, 5]))


def test_thrifty_threshold_is_a_margin_and_violating_arms_still_get_resets() -> None:
    params = PARAMS.model_copy(update={"thrifty_threshold": 0.5, "thrifty_alpha": 1.0})
    alg = get_algorithm("fleet-td", params, 3, 3, seed=0)
    s = PrioritySignals(t=0, violating=np.array([True, False, False]),
                        goal_risk=np.array([-1.0, 0.0, 1.0]), novelty=np.zeros(3))
    assign = alg.step(s)
    z = np.array([-1.0, 0.0, 1.0]) / (np.std([-1, 0, 1]) + 1e-8)
    np.testing.assert_allclose(alg.last_keys[:, 0], [0.0, 0.0, z[2] - 0.5])
    # Arm 2 is above the threshold, arm 0 violates (reset), arm 1 gets nobody.
    assert assign[2] >= 0 and assign[0] >= 0 and assign[1] == -1
    assert alg.allocator.kinds[0] == "reset" and alg.allocator.kinds[2] == "teleop"
    # A negative threshold makes below-mean arms eligible too.
    low = get_algorithm("fleet-td", PARAMS.model_copy(update={"thrifty_threshold": -2.0}),
                        3, 3, seed=0)
    assert (low.priority.keys(s)[:, 0] > 0).all()


def test_thrifty_needs_its_signals_and_ignores_faulted_arms_in_its_statistics() -> None:
    td = ThriftyPriority(2)
    with pytest.raises(ValueError, match=r"signals.goal_risk is required"):
        td.keys(PrioritySignals(t=0, violating=np.zeros(2, bool), novelty=np.zeros(2)))
    td.keys(PrioritySignals(t=0, violating=np.zeros(2, bool), goal_risk=np.array([1.0, 99.0]),
                            novelty=np.zeros(2), faulted=np.array([False, True])))
    assert td.risk_stats.count == 1 and td.risk_stats.mean == 1.0


# ------------------------------------------------------------------------- Random


def _random_run(budget: float, steps: int, seed: int, n: int = 20, m: int = 5,
                away: float = 0.0) -> tuple[float, list[np.ndarray]]:
    """Random over ``steps``; with ``away`` > 0 each human is away with that chance per
    step (an independent stream, so ``away = 0`` is the run without a mask)."""
    params = PARAMS.model_copy(update={"random_budget": budget, "t_T": 3, "t_R": 4})
    alg = get_algorithm("random", params, n, m, seed=seed)
    rng = np.random.default_rng(seed)
    presence = np.random.default_rng([seed, 1])
    violating = np.zeros(n, bool)
    busy, history = 0, []
    for t in range(steps):
        violating |= rng.random(n) < 0.02
        available = presence.random(m) >= away if away else None
        before = alg.allocator.assignment
        assign = alg.step(PrioritySignals(t=t, violating=violating.copy(),
                                          available=available))
        if available is not None:  # an away human is on no arm, or on its held one
            for j in np.flatnonzero(~available):
                on = np.flatnonzero(assign == j)
                assert on.size == 0 or before[on[0]] == j
        history.append(assign)
        busy += int((assign >= 0).sum())
        # The reset ends at the end of its t_R-th step.
        kinds, served = alg.allocator.kinds, alg.allocator.served
        for i in range(n):
            if kinds[i] == "reset" and served[i] + 1 >= params.t_R:
                violating[i] = False
    assert alg.priority.effort == busy  # type: ignore[attr-defined]
    return busy / (m * steps), history


@pytest.mark.parametrize("budget", [0.1, 0.3, 0.6])
def test_random_matches_its_human_effort_budget(budget: float) -> None:
    fraction, _ = _random_run(budget, steps=2000, seed=3)
    assert fraction == pytest.approx(budget, abs=0.02)


def test_random_with_away_humans_counts_only_the_humans_present() -> None:
    # Every arm Random makes eligible gets a human (effort == busy, checked in the run),
    # none of them away, and the budget's deficit catches up while others are present.
    fraction, _ = _random_run(0.3, steps=2000, seed=3, away=0.4)
    assert fraction == pytest.approx(0.3, abs=0.03)
    # Everybody away most of the time: far below budget, but never a phantom human.
    fraction, _ = _random_run(0.6, steps=300, seed=4, away=0.9)
    assert fraction < 0.6


def test_random_with_zero_budget_assigns_nobody() -> None:
    fraction, _ = _random_run(0.0, steps=100, seed=0)
    assert fraction == 0.0


def test_random_puts_violating_arms_first_and_is_seeded() -> None:
    rp = RandomPriority(6, 2, budget=1.0, seed=0)
    keys = rp.keys(PrioritySignals(t=0, violating=np.array([0, 0, 1, 0, 1, 1], bool)))
    chosen = np.flatnonzero(keys[:, 1] > 0)
    assert len(chosen) == 2 and set(chosen) <= {2, 4, 5}
    assert (keys[chosen, 0] == 1.0).all()
    a = _random_run(0.3, steps=50, seed=9)[1]
    b = _random_run(0.3, steps=50, seed=9)[1]
    assert all((x == y).all() for x, y in zip(a, b, strict=True))


def test_random_refuses_an_allocator_that_is_not_the_one_allocating() -> None:
    alg = get_algorithm("random", PARAMS, 4, 2, seed=0)
    s = PrioritySignals(t=0, violating=np.zeros(4, bool))
    alg.priority.keys(s)
    with pytest.raises(RuntimeError, match=r"Algorithm\.allocator"):
        alg.priority.keys(s)


# ----------------------------------------------------------- common behaviour


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_every_algorithm_runs_resumes_identically_and_zeroes_faulted_arms(name: str) -> None:
    n, m = 6, 2
    rng = np.random.default_rng(5)
    sigs = [PrioritySignals(t=t, violating=rng.random(n) < 0.2, uncertainty=rng.random(n),
                            risk=rng.random(n), goal_risk=rng.random(n),
                            novelty=rng.random(n), ood=rng.random(n),
                            faulted=rng.random(n) < 0.1)
            for t in range(40)]
    alg = get_algorithm(name, PARAMS, n, m, seed=11)
    assert isinstance(alg.priority, PriorityFunction)
    for s in sigs[:20]:
        alg.step(s)
        assert alg.last_keys is not None and alg.last_keys.shape == (n, len(alg.names))
        assert not alg.last_keys[np.asarray(s.faulted)].any()
        assert set(alg.reason(0)) == set(alg.names)
    saved = json.loads(json.dumps(alg.state_dict()))
    twin = get_algorithm(name, PARAMS, n, m, seed=999)
    twin.load_state_dict(saved)
    for s in sigs[20:]:
        assert alg.step(s).tolist() == twin.step(s).tolist()
        np.testing.assert_array_equal(alg.last_keys, twin.last_keys)


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_every_algorithm_takes_an_availability_mask(name: str) -> None:
    n, m = 6, 3
    rng = np.random.default_rng(7)
    sigs = [PrioritySignals(t=t, violating=rng.random(n) < 0.2, uncertainty=rng.random(n),
                            risk=rng.random(n), goal_risk=rng.random(n),
                            novelty=rng.random(n), ood=rng.random(n)) for t in range(40)]
    masks = rng.random((40, m)) < 0.6
    plain, full, masked = (get_algorithm(name, PARAMS, n, m, seed=3) for _ in range(3))
    for s, mask in zip(sigs, masks, strict=True):
        # no mask and an all-True mask: the same allocation, the same state (streams)
        all_in = PrioritySignals(**{**{f: getattr(s, f) for f in s.__slots__},
                                    "available": np.ones(m, bool)})
        assert plain.step(s).tolist() == full.step(all_in).tolist()
        assert json.dumps(plain.state_dict()) == json.dumps(full.state_dict())
        before = masked.allocator.assignment
        away_in = PrioritySignals(**{**{f: getattr(s, f) for f in s.__slots__},
                                     "available": mask})
        after = masked.step(away_in)
        for j in np.flatnonzero(~mask):  # an away human is never newly assigned
            on = np.flatnonzero(after == j)
            assert on.size == 0 or before[on[0]] == j
    with pytest.raises(ValueError, match=r"signals.available must be bool with shape \(3,\)"):
        masked.step(PrioritySignals(t=40, violating=np.zeros(n, bool),
                                    uncertainty=np.zeros(n), risk=np.zeros(n),
                                    goal_risk=np.zeros(n), novelty=np.zeros(n),
                                    ood=np.zeros(n), available=np.ones(2, bool)))


def test_registry_names_and_unknown_names() -> None:
    assert set(ALGORITHM_NAMES) == {"bc", "random", "fleet-ed", "fleet-td", "cur", "cur-i",
                                    "monitor", "c", "u", "r", "cu", "cr", "ur", "uc", "ru",
                                    "cru"}
    assert get_algorithm(" CUR ", PARAMS, 2, 1, 0).name == "cur"
    with pytest.raises(ValueError, match=r"unknown algorithm 'dagger'; valid names: bc, "):
        get_algorithm("dagger", PARAMS, 2, 1, 0)
    with pytest.raises(ValueError, match="for algorithm 'cur', not 'bc'"):
        get_algorithm("bc", PARAMS, 2, 1, 0).load_state_dict(
            get_algorithm("cur", PARAMS, 2, 1, 0).state_dict())


@pytest.mark.parametrize(
    ("kw", "match"),
    [({"uncertainty": None}, r"signals.uncertainty is required"),
     ({"risk": np.array([0.1, np.nan, 0, 0])}, r"signals.risk has NaN for arm\(s\) \[1\]"),
     ({"risk": np.zeros(3)}, r"signals.risk must have shape \(4,\)"),
     ({"violating": np.zeros(4)}, r"signals.violating must be bool"),
     ({"faulted": np.zeros(4, int)}, r"signals.faulted must be bool")],
)
def test_bad_signals_are_clear_value_errors(kw: dict[str, object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        keys_of("cur", 0, **kw)


def test_ordered_priority_rejects_bad_orders() -> None:
    for order in ("", "cc", "cx"):
        with pytest.raises(ValueError, match="order"):
            OrderedPriority(order, 2)
    bad_t = PrioritySignals(t=1.5, violating=np.zeros(1, bool))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"signals\.t must be an int"):
        OrderedPriority("c", 1).keys(bad_t)
