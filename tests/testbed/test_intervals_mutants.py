"""The report's intervals and the betting sets: the edges a mutation run found untested.

Why: testbed/results/intervals.py and testbed/results/betting.py make the intervals a
paper would quote (a mean over trials, a rate over runs, a paired difference with its
p-value, the confidence set of a bounded mean); scripts/mutation.sh showed changes to
them that no test noticed (docs/notes/tests.md, "Tests that can fail"). Each expected
value here comes from the rule the module's docstring states, recomputed by a plain
loop, by enumeration or from a textbook quantile, never from the module's own output.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from test_intervals import _reference_rate_bounds
from test_sequential_cs import _reference_e

from testbed.results.betting import betting_set, wealth
from testbed.results.intervals import (
    Interval,
    _clip01,
    interval,
    paired,
    rate_interval,
    sign_flip_p,
    smallest_p,
)

# Student's t with 2 degrees of freedom has the closed-form quantile (2p - 1) /
# sqrt(2p(1 - p)): the 95th percentile
T_95_2 = 0.9 / math.sqrt(2 * 0.95 * 0.05)


def _exact_sign_flip(d: list[float]) -> float:
    """The share of all 2^n sign patterns whose |sum| reaches the observed |sum|."""
    a = np.asarray(d)
    signs = np.array(list(itertools.product((-1.0, 1.0), repeat=len(a))))
    sums = np.abs(signs @ a)
    return float(np.mean(sums >= abs(a.sum()) * (1 - 1e-9)))


def _reference_plug_in_e(x: list[float], m: float, lo: float, hi: float, horizon: int,
                         alpha: float) -> list[float]:
    """WSR's plug-in bets on [lo, hi], one outcome at a time: the size sqrt(2 log(2 /
    alpha) / (horizon var)), var from the outcomes before with a prior pseudo-observation
    of variance ((hi - lo) / 2)^2 / 4 around the middle, capped at 0.9 / (m - lo) up and
    0.9 / (hi - m) down; the e-value the two wealths' average."""
    half = (hi - lo) / 2
    up = down = 1.0
    ss, total, out = 0.25 * half * half, lo + half, []
    for k, xk in enumerate(x):
        size = math.sqrt(2 * math.log(2 / alpha) / (horizon * ss / (k + 1)))
        up *= 1 + min(size, 0.9 / (m - lo)) * (xk - m)
        down *= 1 - min(size, 0.9 / (hi - m)) * (xk - m)
        out.append((up + down) / 2)
        ss += (xk - total / (k + 1)) ** 2
        total += xk
    return out


def _reference_set(x: list[float], alpha: float, lo: float, hi: float, grid: int,
                   fixed_n: bool) -> list[tuple[float, float]]:
    """After each outcome: the ends of the betting set on a grid of ``grid`` candidates
    strictly inside (lo, hi), the first rejected candidate on each side of the kept ones
    (lo / hi when none is), a candidate rejected once its e-value reaches 1/alpha."""
    ms = [lo + (hi - lo) * k / (grid + 1) for k in range(1, grid + 1)]
    es = [(_reference_plug_in_e(x, m, lo, hi, len(x), alpha) if fixed_n
           else _reference_e(x, m, lo, hi)) for m in ms]
    ends = []
    for t in range(len(x)):
        kept = [j for j, e in enumerate(es) if max(e[:t + 1]) < 1 / alpha]
        ends.append((ms[kept[0] - 1] if kept[0] > 0 else lo,
                     ms[kept[-1] + 1] if kept[-1] < grid - 1 else hi))
    return ends


# ------------------------------------------------------------------ intervals.py
def test_contains_allows_only_a_rounding_error_past_either_end() -> None:
    iv = Interval(0.5, 0.2, 0.8, 3, "t")
    assert iv.contains(0.2) and iv.contains(0.8) and iv.contains(0.5)
    assert iv.contains(0.2 - 5e-13) and iv.contains(0.8 + 5e-13)
    assert iv.contains(0.2 - 1e-12) and iv.contains(0.8 + 1e-12)  # 1e-12 out: still in
    assert not iv.contains(0.2 - 1e-11) and not iv.contains(0.8 + 1e-11)


def test_no_one_or_equal_values_say_so_with_their_count() -> None:
    none = interval([])
    assert (none.n, none.method) == (0, "none")
    assert math.isnan(none.mean) and math.isnan(none.low) and math.isnan(none.high)
    one = interval([0.4])
    assert (one.n, one.method, one.mean) == (1, "one", 0.4) and math.isnan(one.high)
    same = interval([5.0] * 4)
    assert (same.n, same.method, same.mean, same.low, same.high) == (4, "exact", 5.0, 5.0, 5.0)


def test_every_value_equal_means_equal_to_within_1e_12_of_the_mean_or_of_1() -> None:
    assert interval([0.0, 1.5e-12]).method == "t"  # 1.5e-12 apart near 0: a spread
    assert interval([0.0, 0.5e-12]).method == "exact"
    assert interval([0.0, 1e-12]).method == "exact"  # exactly 1e-12 apart: equal
    assert interval([1e9, 1e9 + 1e-4]).method == "exact"  # 1e-12 of 1e9 is 1e-3
    assert interval([1e9, 1e9 + 0.01]).method == "t"


def test_the_t_interval_at_another_level_by_hand() -> None:
    iv = interval([1.0, 2.0, 3.0], level=0.9)
    half = T_95_2 / math.sqrt(3)
    assert (iv.method, iv.n) == ("t", 3)
    assert (iv.low, iv.high) == pytest.approx((2.0 - half, 2.0 + half), rel=1e-12)
    # 1, 2, 4: mean 7/3, sample variance 7/3 (a spread other than 1)
    iv = interval([1.0, 2.0, 4.0], level=0.9)
    half = T_95_2 * math.sqrt(7 / 3) / math.sqrt(3)
    assert (iv.low, iv.high) == pytest.approx((7 / 3 - half, 7 / 3 + half), rel=1e-12)


def test_the_bootstrap_is_bca_at_the_level_with_9999_resamples_from_the_seed() -> None:
    from scipy import stats

    v = np.random.default_rng(12).normal(5.0, 1.0, 11)
    for level, seed in ((0.9, 0), (0.95, 7)):
        iv = interval(v, level=level, seed=seed)
        ci = stats.bootstrap((v,), np.mean, confidence_level=level, n_resamples=9999,
                             method="BCa",
                             random_state=np.random.default_rng(seed)).confidence_interval
        assert (iv.method, iv.n, iv.mean) == ("bootstrap", 11, pytest.approx(v.mean()))
        assert (iv.low, iv.high) == (pytest.approx(ci.low, rel=1e-12),
                                     pytest.approx(ci.high, rel=1e-12))
    assert interval(v) == interval(v, seed=0) != interval(v, seed=1)  # the default seed 0


def test_a_rate_of_no_or_one_run_has_no_interval() -> None:
    one = rate_interval([0.4])
    assert (one.method, one.n, one.mean) == ("one", 1, 0.4)
    assert math.isnan(one.low) and math.isnan(one.high)
    none = rate_interval([])
    assert (none.method, none.n) == ("none", 0) and math.isnan(none.mean)
    assert math.isnan(none.low) and math.isnan(none.high)


def test_clip01_clips_each_end_to_0_1_and_keeps_nan() -> None:
    assert _clip01(-0.2, 1.3) == (0.0, 1.0)
    assert _clip01(0.25, 0.75) == (0.25, 0.75)
    assert _clip01(1.5, -0.5) == (1.0, 0.0)
    low, high = _clip01(math.nan, math.nan)
    assert math.isnan(low) and math.isnan(high)


def test_a_negative_rate_is_refused_and_the_ends_0_and_1_are_not() -> None:
    with pytest.raises(ValueError, match=r"rate must lie in \[0, 1\]") as err:
        rate_interval([0.5, -0.1, 0.9])
    assert str(err.value) == "a rate must lie in [0, 1]"
    assert rate_interval([0.0, 1.0]).method == "betting"


def test_the_rate_switches_to_the_bootstrap_at_10_runs_unless_all_are_equal() -> None:
    v = list(np.random.default_rng(5).uniform(0.6, 0.9, 10))
    assert rate_interval(v[:9]).method == "betting"
    assert rate_interval(v).method == "cluster bootstrap"
    # 1e-12 apart counts as all equal (the betting interval), 2e-12 does not
    assert rate_interval([0.0] * 11 + [1e-12]).method == "betting"
    assert rate_interval([0.0] * 11 + [2e-12]).method == "cluster bootstrap"


def test_the_cluster_bootstrap_is_the_percentile_interval_of_9999_resampled_means() -> None:
    """The rule: RESAMPLES rows of n runs drawn with replacement from default_rng(seed),
    each row's mean, the (1 - level) / 2 and (1 + level) / 2 quantiles."""
    v = np.random.default_rng(6).uniform(0.5, 1.0, 13)
    for level, seed in ((0.95, 0), (0.8, 21)):
        rng = np.random.default_rng(seed)
        means = [float(np.mean(v[rng.integers(0, 13, 13)])) for _ in range(9999)]
        low, high = np.quantile(means, [(1 - level) / 2, (1 + level) / 2])
        iv = rate_interval(list(v), level=level, seed=seed)
        assert iv.method == "cluster bootstrap" and iv.n == 13
        assert iv.mean == pytest.approx(float(np.mean(v)), rel=1e-12)
        assert (iv.low, iv.high) == (pytest.approx(low, abs=1e-12),
                                     pytest.approx(high, abs=1e-12))
    assert rate_interval(list(v)) == rate_interval(list(v), seed=0) != rate_interval(
        list(v), seed=1)  # the default seed 0


def test_the_betting_rate_interval_at_another_level() -> None:
    for values in ([0.9, 0.92, 1.0], [0.2, 0.9, 0.5, 0.6]):
        iv = rate_interval(values, level=0.8)
        assert (iv.low, iv.high) == pytest.approx(_reference_rate_bounds(values, 0.2, 2001),
                                                  abs=1e-12)


def test_smallest_p_by_hand() -> None:
    assert smallest_p(0) == 1.0 and smallest_p(1) == 1.0
    assert smallest_p(2) == 0.5 and smallest_p(16) == 2 / 65536


def test_sign_flip_p_edges_by_enumeration() -> None:
    assert math.isnan(sign_flip_p([]))
    assert sign_flip_p([1e-12] * 4) == 1.0  # within 1e-12 of 0: no difference
    assert sign_flip_p([2e-12] * 4) == pytest.approx(2 / 16)  # only ++++ and ----
    assert sign_flip_p([0.0, 0.0, 0.0]) == 1.0
    d16 = list(np.random.default_rng(16).normal(0.4, 1.0, 16))
    assert sign_flip_p(d16) == pytest.approx(_exact_sign_flip(d16), abs=1e-12)


def test_beyond_16_pairs_the_p_value_is_a_seeded_estimate_of_the_exact_one() -> None:
    d = list(np.random.default_rng(17).normal(0.3, 1.0, 17))
    exact = _exact_sign_flip(d)
    p1 = sign_flip_p(d, seed=1)
    assert p1 == sign_flip_p(d, seed=1) != sign_flip_p(d, seed=2)
    assert p1 == pytest.approx(exact, abs=0.01)  # 100000 patterns: se below 0.002
    assert 0.05 < exact < 0.95  # a p-value the estimate can miss on either side


def test_paired_passes_its_level_and_seed_on() -> None:
    rng = np.random.default_rng(18)
    ref = {k: float(v) for k, v in enumerate(rng.normal(0, 1, 17))}
    alg = {k: v + float(rng.normal(0.3, 1.0)) for k, v in ref.items()}
    diffs = [alg[k] - ref[k] for k in range(17)]
    cmp = paired(alg, ref, level=0.9, seed=5)
    assert cmp.difference == interval(diffs, level=0.9, seed=5)
    assert cmp.difference != interval(diffs, level=0.9, seed=0)
    assert cmp.p_value == sign_flip_p(diffs, seed=5)
    assert cmp.floor == 2 / 2 ** 17
    default = paired(alg, ref)  # level 0.95, seed 0
    assert default.difference == interval(diffs, level=0.95, seed=0)
    assert default.p_value == sign_flip_p(diffs, seed=0) != sign_flip_p(diffs, seed=1)
    assert sign_flip_p(diffs) == sign_flip_p(diffs, seed=0)
    few = paired({0: 1.0, 1: 2.0, 2: 4.0}, {0: 0.0, 1: 0.0, 2: 0.0}, level=0.9)
    # differences 1, 2, 4: mean 7/3, sample variance 7/3; the 90% t interval
    half = T_95_2 * math.sqrt(7 / 3) / math.sqrt(3)
    assert (few.difference.low, few.difference.high) == pytest.approx(
        (7 / 3 - half, 7 / 3 + half), rel=1e-12)


# ------------------------------------------------------------------ betting.py
X01 = [0.3, 0.8, 0.55, 0.9, 0.1, 0.7, 0.65, 0.95]


@pytest.mark.parametrize(("lo", "hi", "m"), [(0.0, 1.0, 0.4), (-2.0, 3.0, 1.1),
                                             (-2.0, 3.0, -1.5)])
def test_agrapa_wealth_on_other_ranges_is_the_plain_loop(lo: float, hi: float,
                                                         m: float) -> None:
    x = [lo + (hi - lo) * v for v in X01]
    assert wealth(x, m, lo, hi).e[0] == pytest.approx(_reference_e(x, m, lo, hi), rel=1e-12)


@pytest.mark.parametrize(("lo", "hi", "m", "alpha"), [(0.0, 1.0, 0.4, 0.05),
                                                      (-1.0, 1.0, 0.2, 0.1),
                                                      (-2.0, 3.0, -0.5, 0.2)])
def test_plug_in_wealth_is_the_plain_loop(lo: float, hi: float, m: float,
                                          alpha: float) -> None:
    x = [lo + (hi - lo) * v for v in X01]
    got = wealth(x, m, lo, hi, horizon=12, alpha=alpha).e[0]
    assert got == pytest.approx(_reference_plug_in_e(x, m, lo, hi, 12, alpha), rel=1e-12)
    if alpha == 0.05:  # the default alpha is 0.05
        assert np.array_equal(wealth(x, m, lo, hi, horizon=12).e, wealth(
            x, m, lo, hi, horizon=12, alpha=0.05).e)


def test_wealth_of_many_rows_is_each_row_alone() -> None:
    rng = np.random.default_rng(20)
    xs = rng.uniform(0.0, 1.0, (3, 6))
    ms = np.array([0.2, 0.5, 0.7])
    for horizon in (None, 6):
        rows = wealth(xs, ms, 0.0, 1.0, horizon, 0.1)  # row r: xs[r] against ms[r]
        one_m = wealth(xs, 0.5, 0.0, 1.0, horizon, 0.1)  # every row against 0.5
        one_x = wealth(xs[1], ms, 0.0, 1.0, horizon, 0.1)  # xs[1] against each m
        for r in range(3):
            alone = wealth(xs[r], ms[r], 0.0, 1.0, horizon, 0.1)
            assert np.array_equal(rows.e[r], alone.e[0])
            assert np.array_equal(rows.lam_up[r], alone.lam_up[0])
            assert np.array_equal(rows.lam_down[r], alone.lam_down[0])
            assert np.array_equal(one_m.e[r], wealth(xs[r], 0.5, 0.0, 1.0, horizon, 0.1).e[0])
            assert np.array_equal(one_x.e[r], wealth(xs[1], ms[r], 0.0, 1.0, horizon, 0.1).e[0])


def test_a_candidate_on_either_end_is_refused_and_one_just_inside_is_not() -> None:
    for m in (-1.0, 1.0, -1.5, 1.5):
        with pytest.raises(ValueError, match="strictly inside"):
            wealth([0.5], m)
    with pytest.raises(ValueError, match="strictly inside"):
        wealth([0.5], [0.0, 0.0, -1.0])
    assert wealth([0.5], [-0.999, 0.999]).e.shape == (2, 1)


def test_betting_set_refuses_what_is_outside_its_range_and_takes_its_ends() -> None:
    for x in ([0.5, -1.5], [float("nan")], [float("inf")], [float("-inf")]):
        with pytest.raises(ValueError, match=r"every outcome must be a number in"):
            betting_set(x, 0.05)
    for alpha in (0.0, -0.1, 1.0):
        with pytest.raises(ValueError, match="alpha must be in"):
            betting_set([0.5], alpha)
    ends = betting_set([-1.0, 1.0, 1.0, -1.0], 0.05)
    assert len(ends.low) == 4 and not np.any(np.isnan(ends.low))


@pytest.mark.parametrize(("lo", "hi", "alpha", "fixed_n"), [
    (0.0, 1.0, 0.1, False), (-2.0, 3.0, 0.2, False), (-1.0, 1.0, 0.1, True),
    (-2.0, 3.0, 0.2, True)])
def test_betting_set_is_the_plain_loops_set_after_every_outcome(
        lo: float, hi: float, alpha: float, fixed_n: bool) -> None:
    x = [lo + (hi - lo) * v for v in X01]
    got = betting_set(x, alpha, lo=lo, hi=hi, grid=99, fixed_n=fixed_n)
    want = _reference_set(x, alpha, lo, hi, 99, fixed_n)
    assert list(got.low) == pytest.approx([w[0] for w in want], abs=1e-12)
    assert list(got.high) == pytest.approx([w[1] for w in want], abs=1e-12)
    # and the set narrows to something strictly inside the range (the test bites)
    assert lo < got.low[-1] < got.high[-1] < hi


def test_the_bets_by_hand_for_two_outcomes_of_plus_1() -> None:
    """At m = 0 on [-1, 1]: the first bets are +-0.9 (aGRAPA's prior pseudo-observation,
    mean +-1/2 and variance 1/4, asks for +-1, capped); after a +1 the bet up stays at
    its cap, the bet down is 0 (its running mean (-1/2 + 1) / 2 is positive)."""
    w = wealth([1.0, 1.0], 0.0)
    assert w.lam_up[0].tolist() == [0.9, 0.9]
    assert w.lam_down[0].tolist() == [-0.9, 0.0]
    assert w.up[0].tolist() == pytest.approx([1.9, 3.61])
    assert w.down[0].tolist() == pytest.approx([0.1, 0.1])


def test_one_outcome_given_as_a_number() -> None:
    one, listed = betting_set(0.5, 0.1), betting_set([0.5], 0.1)
    assert np.array_equal(one.low, listed.low) and np.array_equal(one.high, listed.high)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_the_set_ends_at_the_outermost_candidate_when_the_next_is_kept(sign: float) -> None:
    """On a grid of 3 (-0.5, 0, 0.5), alpha 1/8: four outcomes of +1 bring the e-value
    at -0.5 to 9.2 (rejected) and at 0 to (1.9^4 + 0.1) / 2 = 6.6 (kept), so the lower
    end is -0.5, the first candidate, not -1 (and mirrored for -1)."""
    got = betting_set([sign] * 4, 0.125, grid=3)
    want = _reference_set([sign] * 4, 0.125, -1.0, 1.0, 3, False)
    assert list(got.low) == [w[0] for w in want] and list(got.high) == [w[1] for w in want]
    assert (got.low[-1], got.high[-1]) == ((-0.5, 1.0) if sign > 0 else (-1.0, 0.5))


def test_an_e_value_exactly_at_1_over_alpha_rejects() -> None:
    """Four outcomes of +1 on [-1, 1]: at m = 0 the e-value is (1.9^4 + 0.1) / 2 =
    6.56605 (both bets capped at 0.9, the bet down falling to 0 after the first); at
    the alpha whose 1/alpha is that float exactly, 0 is rejected (Ville: reaching
    1/alpha), so 0 is the set's lower end, not a point inside it."""
    e = wealth([1.0] * 4, 0.0).e[0]
    assert e[-1] == pytest.approx((1.9 ** 4 + 0.1) / 2, rel=1e-12)
    alpha = 0.1522985661090001
    assert 1 / alpha == e[-1]
    cs = betting_set([1.0] * 4, alpha)
    assert cs.low[-1] == 0.0 and cs.high[-1] == 1.0
    assert cs.low[-2] < 0.0  # the outcome before: 0 still inside
