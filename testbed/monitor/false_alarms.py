"""The realised false-alarm rate of an alarm over runs, with a one-sided upper bound that
respects clustering by run (issue 45, item 2).

Why clustered: a run's episodes share its policy, its people and its alarm's state (one
threshold judges many of them), so they are not independent draws; a binomial standard
error over the pooled episodes treats 6 runs of 80 episodes as 480 coin flips and is too
narrow when runs differ. Why not a bootstrap over runs: with the 3-6 runs a protocol
gives, resampling whole runs sees at most a handful of distinct values and is
anti-conservative (and says 0 with certainty when no run alarmed). Why not Student's t
on the per-run rates: a width of 0 when every run says 0, and runs of unequal size
weigh alike.

The bound here is Korn & Graubard's (1998) for a proportion from clustered data: the
Clopper-Pearson bound (exact for binomial counts, valid at 0 events) on an *effective*
number of episodes, the pooled count divided by the design effect (the between-run
variance of the ratio estimator over the binomial one, never below 1), times
(z / t_{runs-1})^2 for the few runs the variance is estimated from. With one run there
is no between-run variance to estimate: plain Clopper-Pearson, said so in ``method``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

__all__ = ["CONFIDENCE", "AlarmRate", "alarm_rate"]

CONFIDENCE: Final = 0.95
"""The one-sided bound's confidence."""


@dataclass(frozen=True, slots=True)
class AlarmRate:
    """Alarmed episodes over judged ones, pooled over runs, and the one-sided upper bound
    of the rate (``method`` says how it was computed)."""

    alpha: float
    runs: int
    episodes: int
    fired: int
    rate: float
    upper: float
    method: str

    @property
    def holds(self) -> bool:
        """The upper bound is at most alpha (False when nothing was judged)."""
        return self.upper <= self.alpha


def _cp_upper(x: float, n: float, confidence: float) -> float:
    """Clopper-Pearson's one-sided upper bound for x events in n (real-valued)."""
    if n <= 0:
        return math.nan
    if x >= n:
        return 1.0
    from scipy import stats  # the report's; a robot host's install imports this module without it

    return float(stats.beta.ppf(confidence, x + 1.0, n - x))


def alarm_rate(fired: Sequence[int], judged: Sequence[int], alpha: float,
               confidence: float = CONFIDENCE) -> AlarmRate:
    """Per run the episodes the alarm fired in and those judged; runs that judged none
    do not count. The rate is sum(fired) / sum(judged); the bound is Korn-Graubard's."""
    f = np.asarray(fired, dtype=np.float64)
    n = np.asarray(judged, dtype=np.float64)
    if f.shape != n.shape or (f > n).any() or (f < 0).any():
        raise ValueError("fired and judged must be per run, 0 <= fired <= judged")
    keep = n > 0
    f, n = f[keep], n[keep]
    runs, total, x = int(n.size), float(n.sum()), float(f.sum())
    if runs == 0:
        return AlarmRate(alpha, 0, 0, 0, math.nan, math.nan, "nothing judged")
    p = x / total
    if runs == 1:
        return AlarmRate(alpha, 1, int(total), int(x), p, _cp_upper(x, total, confidence),
                         "Clopper-Pearson (1 run: not clustered)")
    between = runs / (runs - 1) * float(np.sum((f - p * n) ** 2)) / total ** 2
    binomial = p * (1.0 - p) / total
    deff = max(1.0, between / binomial) if binomial > 0 else 1.0
    from scipy import stats

    df_factor = (stats.norm.ppf(confidence) / stats.t.ppf(confidence, runs - 1)) ** 2
    n_eff = total / deff * df_factor
    return AlarmRate(alpha, runs, int(total), int(x), p, _cp_upper(p * n_eff, n_eff, confidence),
                     f"Korn-Graubard, clustered by run (design effect {deff:.2f}, "
                     f"{n_eff:.1f} effective episodes)")
