"""The report's intervals and paired comparisons on examples computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from testbed.results.intervals import (
    BOOTSTRAP_MIN_TRIALS,
    interval,
    paired,
    rate_interval,
    sign_flip_p,
    smallest_p,
)

T_975_2 = 4.302652729911275  # Student's t, 97.5th percentile, 2 degrees of freedom


def test_t_interval_of_three_trials_by_hand() -> None:
    # [1, 2, 3]: mean 2, sample sd 1, se 1/sqrt(3); half-width t(0.975, 2) / sqrt(3)
    iv = interval([1.0, 2.0, 3.0])
    half = T_975_2 / math.sqrt(3)
    assert iv.method == "t" and iv.n == 3
    assert iv.mean == pytest.approx(2.0)
    assert (iv.low, iv.high) == pytest.approx((2.0 - half, 2.0 + half))


def test_degenerate_cases() -> None:
    assert interval([]).method == "none" and math.isnan(interval([]).mean)
    one = interval([0.4])
    assert one.method == "one" and one.mean == 0.4 and math.isnan(one.low)
    same = interval([5.0, 5.0, 5.0])
    assert (same.method, same.low, same.high) == ("exact", 5.0, 5.0)


def test_bootstrap_from_the_switch_count() -> None:
    rng = np.random.default_rng(3)
    v = rng.normal(10.0, 2.0, BOOTSTRAP_MIN_TRIALS)
    iv = interval(v)
    assert iv.method == "bootstrap"
    assert iv.low < v.mean() < iv.high
    # a bootstrap interval is about the t interval's width for normal data
    t_half = 2.262 * v.std(ddof=1) / math.sqrt(len(v))
    assert 0.5 * t_half < (iv.high - iv.low) / 2 < 1.5 * t_half
    assert interval(v[:-1]).method == "t"
    assert interval(v, seed=1) == interval(v, seed=1)  # seeded: the same report twice


def test_identical_to_the_reference_gives_zero_and_p_one() -> None:
    ref = {0: 0.37, 1: 0.35, 2: 0.40}
    cmp = paired(dict(ref), ref)
    assert cmp.diffs == (0.0, 0.0, 0.0)
    assert cmp.difference.mean == 0.0 and cmp.difference.method == "exact"
    assert cmp.p_value == 1.0


def test_a_shifted_copy_gives_the_shift_and_the_floor_of_three_pairs() -> None:
    ref = {0: 0.37, 1: 0.35, 2: 0.40}
    cmp = paired({k: v + 0.1 for k, v in ref.items()}, ref)
    assert cmp.difference.mean == pytest.approx(0.1)
    assert cmp.difference.low == pytest.approx(0.1) == cmp.difference.high
    # all three pairs the same sign: 2 of the 8 sign patterns reach |mean| = 0.1
    assert cmp.p_value == pytest.approx(0.25) == cmp.floor == smallest_p(3)


def test_sign_flip_p_by_enumeration() -> None:
    # diffs (1, 2, -0.5): observed sum 2.5; the 8 patterns' sums are +-2.5, +-3.5, +-1.5,
    # +-0.5, and four of them reach |2.5| -> 4/8
    assert sign_flip_p([1.0, 2.0, -0.5]) == pytest.approx(0.5)
    # (1, 1, 1, -1): |sum| 2; patterns with |sum| >= 2 of 16: sum 4 (2), sum 2 (8) -> 10/16
    assert sign_flip_p([1.0, 1.0, 1.0, -1.0]) == pytest.approx(10 / 16)
    assert smallest_p(5) == pytest.approx(1 / 16)
    assert smallest_p(1) == 1.0
    assert sign_flip_p([3.0]) == 1.0  # one pair: both signs reach it


def test_a_trial_without_both_runs_is_left_out_and_named() -> None:
    cmp = paired({0: 1.0, 1: 2.0, 2: 3.0}, {0: 0.5, 2: 2.0, 3: 9.0})
    assert cmp.keys == (0, 2) and cmp.diffs == (0.5, 1.0)
    assert set(cmp.unpaired) == {1, 3}
    assert cmp.floor == 0.5


def _reference_rate_bounds(v: list[float], alpha: float, grid: int) -> tuple[float, float]:
    """The betting interval on [0, 1], one candidate and one run at a time: WSR's
    predictable plug-in bet sqrt(2 log(2/alpha) / (n var)), capped at 0.9 / m and
    0.9 / (1 - m), the two wealths averaged, a candidate rejected once that reaches
    1/alpha; the ends the first rejected candidates on each side."""
    n = len(v)
    ms = [k / (grid + 1) for k in range(1, grid + 1)]
    kept = []
    for m in ms:
        up = down = 1.0
        total, ss, rejected = 0.5, 0.25 * 0.25, False
        for k, x in enumerate(v):
            size = math.sqrt(2 * math.log(2 / alpha) / (n * ss / (k + 1)))
            up *= 1 + min(size, 0.9 / m) * (x - m)
            down *= 1 - min(size, 0.9 / (1 - m)) * (x - m)
            rejected = rejected or (up + down) / 2 >= 1 / alpha
            ss += (x - total / (k + 1)) ** 2
            total += x
        if not rejected:
            kept.append(ms.index(m))
    return (ms[kept[0] - 1] if kept[0] else 0.0,
            ms[kept[-1] + 1] if kept[-1] < grid - 1 else 1.0)


def test_a_rate_interval_below_10_runs_is_the_betting_interval_by_a_plain_loop() -> None:
    """Issue 45: "0.94 [0.85, 1.04]", a t interval over 3 AUROC near 1. Below 10 runs
    the rate's interval is the betting interval for a mean in [0, 1]: the same ends as a
    plain reimplementation (on the module's 2001-point grid), in [0, 1]."""
    runs = [0.90, 0.92, 1.0]
    assert interval(runs).high > 1.0  # what the table used to print
    for values in (runs, [1.0, 1.0, 1.0], [0.0, 0.02, 0.1], [0.97, 0.99, 1.0, 1.0, 0.995],
                   [0.2, 0.9, 0.5, 0.6], [0.5] * 12):
        iv = rate_interval(values)
        assert iv.method == "betting" and iv.n == len(values)
        assert (iv.low, iv.high) == pytest.approx(_reference_rate_bounds(values, 0.05, 2001),
                                                  abs=1e-12), values
        assert 0.0 <= iv.low < iv.mean < iv.high <= 1.0 or iv.mean in (0.0, 1.0), values
    # three AUROC of 1: at least 0.27, near the Clopper-Pearson bound of 3 of 3 (0.292),
    # not [1, 1] (every run equal is no proof the mean is that value)
    ones = rate_interval([1.0, 1.0, 1.0])
    assert (round(ones.low, 4), ones.high) == (0.2707, 1.0)
    assert rate_interval([0.5] * 3).low == pytest.approx(0.1334, abs=1e-4)
    assert rate_interval([0.4]).method == "one"


@pytest.mark.parametrize("n", [3, 9])
def test_the_betting_interval_covers_a_known_mean_at_least_as_often_as_it_says(n: int) -> None:
    """500 replays (seed fixed) of n runs from Bernoulli and Beta rates of known mean:
    the 95% interval holds the mean in at least 95% of them."""
    rng = np.random.default_rng(450 + n)
    for name, draw, mean in (
            ("bernoulli 0.9", lambda: (rng.random(n) < 0.9).astype(float), 0.9),
            ("beta(2, 5)", lambda: rng.beta(2.0, 5.0, n), 2 / 7),
            ("beta(9, 1)", lambda: rng.beta(9.0, 1.0, n), 0.9)):
        hits = sum(rate_interval(list(draw())).contains(mean) for _ in range(500))
        assert hits / 500 >= 0.95, (name, n, hits / 500)


def test_a_rate_outside_0_1_is_refused() -> None:
    with pytest.raises(ValueError, match=r"rate must lie in \[0, 1\]"):
        rate_interval([0.5, 1.2, 0.9])


def test_a_rate_interval_from_10_runs_is_a_seeded_bootstrap_of_the_runs() -> None:
    v = list(np.random.default_rng(4).uniform(0.85, 1.0, 12))
    iv = rate_interval(v, seed=3)
    assert iv.method == "cluster bootstrap" and iv == rate_interval(v, seed=3)
    assert rate_interval(v, seed=4) != iv  # the seed is what it draws from
    # the percentile interval of the mean of 12 runs drawn with replacement: about the
    # normal interval of the mean with the runs' spread (sd / sqrt(n), ddof 0)
    half = 1.96 * float(np.std(v)) / math.sqrt(len(v))
    assert iv.low == pytest.approx(np.mean(v) - half, abs=0.004)
    assert iv.high == pytest.approx(np.mean(v) + half, abs=0.004)
