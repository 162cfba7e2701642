"""The realised false-alarm rate's one-sided bound, value by value (issue 45, item 5: tests
that notice a change to ``testbed/monitor/false_alarms.py``). Each expected value is
derived here from its definition: Clopper-Pearson's upper bound as the p at which the
binomial's lower tail is 1 - confidence (solved by root finding, not by the beta
quantile the module uses), and Korn-Graubard's effective episodes worked out by hand."""

from __future__ import annotations

import math

import pytest
from scipy import optimize, stats

from testbed.monitor.false_alarms import AlarmRate, _cp_upper, alarm_rate

Z95 = 1.6448536269514722
"""The standard normal's 95 % quantile."""


def cp_upper_by_root(x: int, n: int, confidence: float = 0.95) -> float:
    """Clopper-Pearson's one-sided upper bound for x of n from its definition: the p at
    which P(Binomial(n, p) <= x) = 1 - confidence."""
    return float(optimize.brentq(lambda p: stats.binom.cdf(x, n, p) - (1 - confidence),
                                 1e-12, 1 - 1e-12, xtol=1e-14))


def test_one_run_is_clopper_pearson_with_its_counts_and_its_method() -> None:
    r = alarm_rate([2], [10], 0.05)
    assert (r.alpha, r.runs, r.episodes, r.fired) == (0.05, 1, 10, 2)
    assert r.rate == pytest.approx(0.2)
    assert r.upper == pytest.approx(cp_upper_by_root(2, 10), abs=1e-9)
    assert r.method == "Clopper-Pearson (1 run: not clustered)"
    assert not r.holds
    # another confidence is another bound (the argument is used)
    assert alarm_rate([2], [10], 0.05, confidence=0.8).upper == pytest.approx(
        cp_upper_by_root(2, 10, 0.8), abs=1e-9)
    # the ints of the counts are ints
    assert isinstance(r.episodes, int) and isinstance(r.fired, int)


def test_every_episode_alarmed_bounds_the_rate_by_one() -> None:
    assert alarm_rate([5], [5], 0.05).upper == 1.0
    both = alarm_rate([10, 5], [10, 5], 0.05)  # p = 1: no binomial variance, deff 1
    assert both.upper == 1.0 and both.rate == 1.0 and "design effect 1.00" in both.method
    assert _cp_upper(3.0, 3.0, 0.95) == 1.0


def test_no_episode_is_no_bound() -> None:
    assert math.isnan(_cp_upper(0.0, 0.0, 0.95))
    assert math.isnan(_cp_upper(0.0, -1.0, 0.95))
    nothing = alarm_rate([0, 0], [0, 0], 0.1)
    assert (nothing.alpha, nothing.runs, nothing.episodes, nothing.fired) == (0.1, 0, 0, 0)
    assert math.isnan(nothing.rate) and math.isnan(nothing.upper)
    assert nothing.method == "nothing judged" and not nothing.holds
    assert alarm_rate([], [], 0.1).runs == 0


def test_the_design_effect_of_two_disagreeing_runs_worked_by_hand() -> None:
    """fired 2 of 10 and 0 of 10: p = 0.1, residuals f - p n = 1 and -1, the ratio
    estimator's variance 2/1 x 2 / 20^2 = 0.01, the binomial's 0.1 x 0.9 / 20 = 0.0045:
    design effect 20/9; effective episodes 20 / (20/9) x (z / t_1)^2 = 9 (z / t_1)^2."""
    r = alarm_rate([2, 0], [10, 10], 0.05)
    t1 = math.tan(math.pi * (0.95 - 0.5))  # Student's t with 1 df is Cauchy
    n_eff = 9.0 * (Z95 / t1) ** 2
    assert (r.runs, r.episodes, r.fired, r.rate) == (2, 20, 2, pytest.approx(0.1))
    assert r.method == (f"Korn-Graubard, clustered by run (design effect 2.22, "
                        f"{n_eff:.1f} effective episodes)")
    expected = stats.beta.ppf(0.95, 0.1 * n_eff + 1.0, 0.9 * n_eff)
    assert r.upper == pytest.approx(expected, rel=1e-9)
    # with the counts swapped between the runs, the same
    assert alarm_rate([0, 2], [10, 10], 0.05).upper == pytest.approx(expected, rel=1e-9)


def test_runs_of_unequal_size_are_weighed_by_their_size() -> None:
    """3 of 20, 1 of 10, 0 of 10: p = 4/40 = 0.1, residuals f - p n = 1, 0, -1 (each
    run against its own size), the ratio estimator's variance 3/2 x 2 / 40^2 = 0.001875,
    below the binomial's 0.09 / 40 = 0.00225: the design effect stays 1, and the
    effective episodes are 40 (z / t_2)^2 (t_2 at 0.95: 2.919986)."""
    r = alarm_rate([3, 1, 0], [20, 10, 10], 0.05)
    t2 = 2.919985580353726
    n_eff = 40.0 * (Z95 / t2) ** 2
    assert r.method == ("Korn-Graubard, clustered by run (design effect 1.00, "
                        f"{n_eff:.1f} effective episodes)")
    assert r.upper == pytest.approx(stats.beta.ppf(0.95, 0.1 * n_eff + 1.0, 0.9 * n_eff),
                                    rel=1e-9)
    # the same pooled 4 of 40 lumped in one run: residuals 2, -1, -1, variance
    # 3/2 x 6 / 1600 = 0.005625, design effect 2.5, 16 (z / t_2)^2 effective episodes
    lumped = alarm_rate([4, 0, 0], [20, 10, 10], 0.05)
    assert "design effect 2.50, " in lumped.method
    m = 16.0 * (Z95 / t2) ** 2
    assert lumped.upper == pytest.approx(stats.beta.ppf(0.95, 0.1 * m + 1.0, 0.9 * m),
                                         rel=1e-9)


def test_counts_that_are_not_per_run_counts_are_refused() -> None:
    for fired, judged in (([1, 0], [3]), ([4], [3]), ([-1], [3])):
        with pytest.raises(ValueError) as err:
            alarm_rate(fired, judged, 0.05)
        assert str(err.value) == "fired and judged must be per run, 0 <= fired <= judged"
    assert alarm_rate([3], [3], 0.05).fired == 3  # fired = judged is fine
    assert alarm_rate([0], [3], 0.05).fired == 0


def test_holds_is_upper_at_most_alpha() -> None:
    def rate(upper: float) -> AlarmRate:
        return AlarmRate(0.05, 1, 10, 0, 0.0, upper, "m")

    assert rate(0.05).holds and rate(0.049).holds and not rate(0.0501).holds
    assert not rate(math.nan).holds


def test_a_run_that_judged_one_episode_counts() -> None:
    """Only a run that judged none is left out: one judged episode is a run."""
    one = alarm_rate([1], [1], 0.05)
    assert (one.runs, one.episodes, one.fired, one.upper) == (1, 1, 1, 1.0)
    two = alarm_rate([0, 0], [1, 4], 0.05)
    assert (two.runs, two.episodes) == (2, 5)
