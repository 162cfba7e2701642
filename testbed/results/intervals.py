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
:func:`rate_interval`: below ``BOOTSTRAP_MIN_TRIALS`` values, Student's t on the logit
scale mapped back; from that many on, a percentile bootstrap clustered by run (whole runs
resampled with replacement, the mean recomputed; seeded); clipped to [0, 1] either way.

scipy does the arithmetic (``scipy.stats.t``, ``bootstrap``, ``permutation_test``); this
module decides which applies and keeps the answer as plain numbers for the tables.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

__all__ = ["BOOTSTRAP_MIN_TRIALS", "EXACT_MAX_PAIRS", "LEVEL", "LOGIT_EPS", "Interval",
           "Paired", "interval", "paired", "rate_interval", "sign_flip_p", "smallest_p"]

LEVEL: Final = 0.95
BOOTSTRAP_MIN_TRIALS: Final = 10
"""From this many trials a BCa bootstrap over trials; below, Student's t."""
EXACT_MAX_PAIRS: Final = 16
"""Up to this many pairs the sign-flip test enumerates all 2^n patterns (65536); beyond,
100000 random patterns (seeded), and the p-value is an estimate."""
RESAMPLES: Final = 9999
LOGIT_EPS: Final = 0.01
"""A rate below this or above 1 minus it (an AUROC of 1 is common) enters the logit as
this far inside [0, 1]: the logit of 1 is infinite, and a run's AUROC of 1 from a few
dozen positives says no more than 0.99 (a smaller value would let one such run decide
the interval's width)."""
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
    """The mean of ``values`` (one rate in [0, 1] per run) with a ``level`` interval that
    stays in [0, 1] (module docstring: the rule). Below ``BOOTSTRAP_MIN_TRIALS`` runs
    (method ``logit t``) the interval is widened where needed to hold the plain mean it
    is shown beside (the logit scale centres on another mean); from that many on (method
    ``cluster bootstrap``) it is the percentile interval of ``RESAMPLES`` means of runs
    drawn with replacement from a generator seeded with ``seed``."""
    v = np.asarray(values, dtype=float)
    n = len(v)
    if n < 2 or np.ptp(v) <= _TOL * max(1.0, abs(float(v.mean()))):
        iv = interval(v, level, seed)
        return Interval(iv.mean, *_clip01(iv.low, iv.high), iv.n, iv.method)
    mean = float(v.mean())
    if n < BOOTSTRAP_MIN_TRIALS:
        from scipy import stats

        z = _logit(np.clip(v, LOGIT_EPS, 1 - LOGIT_EPS))
        half = float(stats.t.ppf(0.5 + level / 2, n - 1)) * float(z.std(ddof=1)) / math.sqrt(n)
        low, high = _expit(float(z.mean()) - half), _expit(float(z.mean()) + half)
        return Interval(mean, *_clip01(min(low, mean), max(high, mean)), n, "logit t")
    rng = np.random.default_rng(seed)
    means = v[rng.integers(0, n, size=(RESAMPLES, n))].mean(axis=1)
    low, high = np.quantile(means, [0.5 - level / 2, 0.5 + level / 2])
    return Interval(mean, *_clip01(float(low), float(high)), n, "cluster bootstrap")


def _logit(p: np.ndarray) -> np.ndarray:
    return np.log(p / (1 - p))


def _expit(x: float) -> float:
    return 1.0 / (1.0 + math.exp(-x)) if x >= 0 else math.exp(x) / (1.0 + math.exp(x))


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
