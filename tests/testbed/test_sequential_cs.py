"""The confidence sequence of each paired difference (issue 45, item 3): the betting set
of testbed/results/betting.py on the sequential test's clipped scale. Checked against the
e-process it extends (the same wealths at 0), by simulation with a fixed seed (a known
mean is left out at some trial in at most alpha of the replays, looking after every
trial), and against a plain-Python reimplementation of the bets."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.results.betting import CAP, betting_set, wealth
from testbed.results.sequential import bets, confidence_sequence, e_values, outcomes


def _reference_e(x: list[float], m: float, lo: float = -1.0, hi: float = 1.0) -> list[float]:
    """aGRAPA's two wealths on x - m, one number at a time (the module docstring's rule)."""
    half = (hi - lo) / 2
    out, up, down = [], 1.0, 1.0
    stats = {1: [0.5 * half, 0.25 * half * half], -1: [-0.5 * half, 0.25 * half * half]}
    for k, xk in enumerate(x):
        y = xk - m
        lam = {}
        for side in (1, -1):
            s, q = stats[side]
            mu = s / (k + 1)
            g = mu / (q / (k + 1) + mu * mu)
            lam[side] = (min(max(g, 0.0), CAP / (m - lo)) if side == 1
                         else max(min(g, 0.0), -CAP / (hi - m)))
            stats[side] = [s + y, q + (y - mu) ** 2]
        up *= 1 + lam[1] * y
        down *= 1 + lam[-1] * y
        out.append((up + down) / 2)
    return out


def test_at_zero_the_wealths_are_the_sequential_tests_own() -> None:
    rng = np.random.default_rng(7)
    d = rng.standard_t(2, (50, 15))
    b = bets(d)
    w = wealth(outcomes(d), 0.0)
    assert np.array_equal(w.up, b.up) and np.array_equal(w.down, b.down)
    assert np.array_equal(w.e, e_values(d))


def test_zero_leaves_the_sequence_exactly_when_the_pair_is_settled() -> None:
    rng = np.random.default_rng(8)
    for alpha in (0.05, 0.025):
        for _ in range(40):
            d = rng.normal(rng.uniform(-2, 2), 1.0, 12)
            cs = confidence_sequence(d, alpha)
            ever = np.maximum.accumulate(e_values(d)) >= 1 / alpha
            assert np.array_equal(~((cs.low < 0) & (cs.high > 0)), ever), (d, alpha)
    # six -4s: e 23.6 >= 20 at the sixth, not before; below 0 from then on
    cs = confidence_sequence([-4.0] * 7, 0.05)
    assert np.all(cs.high[:5] > 0) and cs.high[5] < 0 and cs.high[6] < cs.high[5]
    assert cs.low[-1] == -1.0


def test_the_set_is_what_a_plain_reimplementation_of_the_bets_keeps() -> None:
    x = [0.3, -0.2, 0.9, 0.5, 0.7, -0.1, 0.8, 0.6]
    grid = 199  # step 0.01 on [-1, 1]
    ms = [-1 + k / 100 for k in range(1, 200)]
    kept = [m for m in ms if max(_reference_e(x, m)) < 1 / 0.1]
    got = betting_set(x, 0.1, grid=grid)
    # the ends: the first candidates rejected on each side
    assert got.low[-1] == pytest.approx(kept[0] - 0.01)
    assert got.high[-1] == pytest.approx(min(1.0, kept[-1] + 0.01))
    assert (round(got.low[-1], 9), round(got.high[-1], 9)) == (-0.08, 0.9)
    for m in (-0.5, 0.0, 0.37, 0.9):
        assert wealth(x, m).e[0] == pytest.approx(_reference_e(x, m), rel=1e-12)


@pytest.mark.parametrize("mean", [-0.6, 0.0, 0.35])
def test_a_known_mean_is_left_out_at_some_trial_in_at_most_alpha_of_the_replays(
        mean: float) -> None:
    """Looking after every one of 25 outcomes, two bounded shapes with the mean known."""
    rng = np.random.default_rng(2045)
    alpha, replays, n = 0.1, 300, 25
    p = (mean + 1) / 2
    shapes = {"+-1 coin": np.where(rng.random((replays, n)) < p, 1.0, -1.0),
              "beta": 2 * rng.beta(4 * p, 4 * (1 - p), (replays, n)) - 1}
    for name, xs in shapes.items():
        missed = 0
        for x in xs:
            cs = betting_set(x, alpha, grid=399)
            missed += bool(np.any((cs.low > mean) | (cs.high < mean) | np.isnan(cs.low)))
        assert missed / replays <= alpha, (name, missed / replays)
        # and it narrows: after 25 outcomes the set is well inside [-1, 1]
        assert cs.high[-1] - cs.low[-1] < 1.6


def test_a_shifted_mean_is_found_and_the_set_holds_it() -> None:
    rng = np.random.default_rng(11)
    x = np.clip(rng.normal(0.5, 0.3, 60), -1, 1)
    cs = betting_set(x, 0.05)
    assert 0 < cs.low[-1] < x.mean() < cs.high[-1]
    assert np.all(np.diff(cs.low[~np.isnan(cs.low)]) >= 0)  # the running intersection
    assert np.all(np.diff(cs.high[~np.isnan(cs.high)]) <= 0)


def test_bad_inputs_are_refused() -> None:
    with pytest.raises(ValueError, match=r"in \[-1.0, 1.0\]"):
        betting_set([0.5, 1.5], 0.05)
    with pytest.raises(ValueError, match="alpha"):
        betting_set([0.5], 1.0)
    with pytest.raises(ValueError, match="strictly inside"):
        wealth([0.5], 1.0)
    empty = betting_set([], 0.05)
    assert len(empty.low) == 0 and len(empty.high) == 0  # no outcome: no set yet
