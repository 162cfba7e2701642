"""Intervals and paired comparisons for the report: what a few trials do and do not show.

Why here, and why these methods. A protocol runs every algorithm once per trial, and the
runs of one trial share theta_0 and the trial's seed, so two algorithms pair by trial:
the per-trial difference removes what the trial's draw shares. The report gives

* for every metric and algorithm, a 95% interval of the mean over trials
  (:func:`interval`): Student's t with n - 1 degrees of freedom for fewer than
  ``BOOTSTRAP_MIN_TRIALS`` trials, a BCa bootstrap over trials from that many on. A
  bootstrap of 3 trials has 10 distinct resamples and an interval that is too narrow;
  t assumes the mean is about normal, which 3 trials cannot check, so the report says
  which method each cell used;
* for every algorithm against a reference (C.U.R. unless named), the paired difference
  per trial with its interval, and the exact sign-flip p-value (:func:`sign_flip_p`):
  under "no difference" each pair's sign is a coin, so the 2^n sign patterns are equally
  likely and the p-value is the share whose |mean difference| reaches the observed one.
  It needs no normality; its floor is 2 / 2^n (:func:`smallest_p`): 0.25 for 3 trials,
  so 3 trials can never reach p < 0.05, however large the difference.

A share or a rank statistic (an AUROC, an average precision, a recall) lives in [0, 1],
where a t interval of a few values near 1 runs past 1 ("0.94 [0.85, 1.04]"). For those
:func:`rate_interval`: below ``BOOTSTRAP_MIN_TRIALS`` runs (or when every run gave the
same value) the betting confidence interval for a mean bounded in [0, 1] (Waudby-Smith
and Ramdas, JRSS-B 2023; :mod:`testbed.results.betting`), valid at any number of runs
under one assumption, that the runs' values are independent draws with one mean (no
normality, no variance estimate that three values cannot give); from that many on, a
percentile bootstrap clustered by run (whole runs resampled with replacement, the mean
recomputed; seeded). Both lie in [0, 1].

scipy does the arithmetic (``scipy.stats.t``, ``bootstrap``, ``permutation_test``); this
module decides which applies and keeps the answer as plain numbers for the tables.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

__all__ = ["BOOTSTRAP_MIN_TRIALS", "EXACT_MAX_PAIRS", "LEVEL", "Interval",
           "Paired", "interval", "paired", "rate_interval", "sign_flip_p", "smallest_p"]

LEVEL: Final = 0.95
BOOTSTRAP_MIN_TRIALS: Final = 10
"""From this many trials a BCa bootstrap over trials; below, Student's t."""
EXACT_MAX_PAIRS: Final = 16
"""Up to this many pairs the sign-flip test enumerates all 2^n patterns (65536); beyond,
100000 random patterns (seeded), and the p-value is an estimate."""
RESAMPLES: Final = 9999
_TOL: Final = 1e-12


@dataclass(frozen=True, slots=True)
class Interval:
    """A mean and its interval over ``n`` values, and how it was made."""

    mean: float
    low: float
    high: float
    n: int
    method: str
    """``t``, ``bootstrap``, ``exact`` (every value equal: no spread to estimate),
    ``one`` (a single value: no interval) or ``none`` (no values)."""

    def contains(self, x: float) -> bool:
        return self.low - _TOL <= x <= self.high + _TOL


def interval(values: Sequence[float], level: float = LEVEL, seed: int = 0) -> Interval:
    """The mean of ``values`` with its ``level`` interval (module docstring: the rule)."""
    v = np.asarray(values, dtype=float)
    n = len(v)
    if n == 0:
        return Interval(math.nan, math.nan, math.nan, 0, "none")
    mean = float(v.mean())
    if n == 1:
        return Interval(mean, math.nan, math.nan, 1, "one")
    if np.ptp(v) <= _TOL * max(1.0, abs(mean)):
        return Interval(mean, mean, mean, n, "exact")
    if n < BOOTSTRAP_MIN_TRIALS:
        from scipy import stats

        half = float(stats.t.ppf(0.5 + level / 2, n - 1)) * float(v.std(ddof=1)) / math.sqrt(n)
        return Interval(mean, mean - half, mean + half, n, "t")
    from scipy import stats

    res = stats.bootstrap((v,), np.mean, confidence_level=level, n_resamples=RESAMPLES,
                          method="BCa", random_state=np.random.default_rng(seed))
    ci = res.confidence_interval
    return Interval(mean, float(ci.low), float(ci.high), n, "bootstrap")


def rate_interval(values: Sequence[float], level: float = LEVEL, seed: int = 0) -> Interval:
    """The mean of ``values`` (one rate in [0, 1] per run, in run order) with a ``level``
    interval in [0, 1] (module docstring: the rule). Below ``BOOTSTRAP_MIN_TRIALS`` runs,
    or all runs equal (method ``betting``): the betting interval of
    :func:`testbed.results.betting.betting_set` on [0, 1] after the last run (every mean
    whose e-value stayed below ``1 / (1 - level)`` over the runs). From that many on
    (method ``cluster bootstrap``): the percentile interval of ``RESAMPLES`` means of
    runs drawn with replacement from a generator seeded with ``seed``. One run: no
    interval (``one``)."""
    v = np.asarray(values, dtype=float)
    n = len(v)
    if n < 2:
        iv = interval(v, level, seed)
        return Interval(iv.mean, *_clip01(iv.low, iv.high), iv.n, iv.method)
    if np.any(v < 0) or np.any(v > 1):
        raise ValueError("a rate must lie in [0, 1]")
    mean = float(v.mean())
    if n < BOOTSTRAP_MIN_TRIALS or np.ptp(v) <= _TOL:
        from testbed.results.betting import betting_set

        cs = betting_set(v, 1 - level, lo=0.0, hi=1.0, fixed_n=True)
        return Interval(mean, float(cs.low[-1]), float(cs.high[-1]), n, "betting")
    rng = np.random.default_rng(seed)
    means = v[rng.integers(0, n, size=(RESAMPLES, n))].mean(axis=1)
    low, high = np.quantile(means, [0.5 - level / 2, 0.5 + level / 2])
    return Interval(mean, *_clip01(float(low), float(high)), n, "cluster bootstrap")


def _clip01(low: float, high: float) -> tuple[float, float]:
    """``low``, ``high`` clipped to [0, 1] (NaN stays NaN: no interval)."""
    return (low if math.isnan(low) else min(1.0, max(0.0, low)),
            high if math.isnan(high) else min(1.0, max(0.0, high)))


def smallest_p(n: int) -> float:
    """The smallest two-sided sign-flip p-value ``n`` pairs can give: 2 / 2^n (1 for n <= 1)."""
    return 1.0 if n <= 1 else min(1.0, 2.0 / 2.0 ** n)


def sign_flip_p(diffs: Sequence[float], seed: int = 0) -> float:
    """Two-sided p-value of "the mean difference is 0" by flipping each pair's sign.

    Exact over all 2^n patterns up to ``EXACT_MAX_PAIRS`` pairs (scipy's
    ``permutation_test`` with ``permutation_type="samples"`` enumerates them). All
    differences 0: every pattern ties the observed 0, p = 1."""
    d = np.asarray(diffs, dtype=float)
    if len(d) == 0:
        return math.nan
    if len(d) == 1 or np.all(np.abs(d) <= _TOL):
        return 1.0  # one pair: both signs reach it; all 0: every pattern ties
    from scipy import stats

    res = stats.permutation_test(
        (d, np.zeros_like(d)), lambda x, y, axis: np.mean(x - y, axis=axis),
        permutation_type="samples", alternative="two-sided", vectorized=True,
        n_resamples=np.inf if len(d) <= EXACT_MAX_PAIRS else 100_000,
        random_state=np.random.default_rng(seed))
    return float(min(1.0, res.pvalue))


@dataclass(frozen=True, slots=True)
class Paired:
    """One algorithm against the reference, trial by trial."""

    keys: tuple[Hashable, ...]
    """The trials both have a finished run of, in order."""
    diffs: tuple[float, ...]
    """Per trial: the algorithm's value minus the reference's."""
    difference: Interval
    p_value: float
    unpaired: tuple[Hashable, ...]
    """Trials only one of the two has (left out of the comparison)."""

    @property
    def floor(self) -> float:
        """The smallest p-value these many pairs could give."""
        return smallest_p(len(self.diffs))


def paired(values: Mapping[Hashable, float], reference: Mapping[Hashable, float],
           level: float = LEVEL, seed: int = 0) -> Paired:
    """The paired comparison of ``values`` against ``reference``, both keyed by trial.

    A trial with a run of only one of the two is left out (``unpaired``): a difference
    needs both, and filling one in would invent a run."""
    keys = tuple(k for k in values if k in reference)
    unpaired = tuple([k for k in values if k not in reference]
                     + [k for k in reference if k not in values])
    diffs = tuple(float(values[k]) - float(reference[k]) for k in keys)
    return Paired(keys, diffs, interval(diffs, level, seed), sign_flip_p(diffs, seed),
                  unpaired)
