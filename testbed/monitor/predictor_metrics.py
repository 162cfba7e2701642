"""How well a score predicts a binary label: ranking, precision, lead time, false alarms,
calibration.

Why these and why written here: AUROC says how often a failing push outranks a fine one
(threshold-free, blind to the base rate); average precision says what an alarm is worth
when failures are rare (its floor is the base rate, not 0.5); the lead time says how
early a person would be called; false alarms per successful episode say how often that
person is called for nothing; the reliability table says whether a score that claims to
be a probability (the safety critic's risk) is one. AUROC is the Mann-Whitney statistic
on scipy's average ranks (ties count half); the rest is a few lines of numpy, not worth a
dependency (scikit-learn's versions agree with these on ties: the tests check known
values).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
from scipy.stats import binomtest, rankdata

__all__ = ["LeadTime", "ReliabilityBin", "auroc", "average_precision", "lead_time",
           "reliability"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
RELIABILITY_BINS: Final = 10


def _checked(scores: npt.ArrayLike, labels: npt.ArrayLike) -> tuple[FloatArray, BoolArray]:
    s = np.asarray(scores, dtype=np.float64)
    y = np.asarray(labels, dtype=bool)
    if s.shape != y.shape or s.ndim != 1:
        raise ValueError(f"scores {s.shape} and labels {y.shape} must be equal 1-d shapes")
    if np.isnan(s).any():
        raise ValueError("scores have NaN: leave the pushes without a score out first")
    return s, y


def auroc(scores: npt.ArrayLike, labels: npt.ArrayLike) -> float:
    """P(score of a positive > score of a negative) + half the ties; NaN without both."""
    s, y = _checked(scores, labels)
    pos, neg = int(y.sum()), int((~y).sum())
    if pos == 0 or neg == 0:
        return float("nan")
    ranks = rankdata(s)
    return float((ranks[y].sum() - pos * (pos + 1) / 2) / (pos * neg))


def average_precision(scores: npt.ArrayLike, labels: npt.ArrayLike) -> float:
    """Sum over distinct thresholds (high to low) of precision x recall gained; NaN
    without a positive. Tied scores are one threshold (as scikit-learn's)."""
    s, y = _checked(scores, labels)
    pos = int(y.sum())
    if pos == 0:
        return float("nan")
    order = np.argsort(-s, kind="stable")
    s, y = s[order], y[order]
    last = np.r_[np.flatnonzero(np.diff(s)), s.size - 1]  # the end of each tie group
    tp = np.cumsum(y)[last]
    precision = tp / (last + 1)
    recall_gain = np.diff(np.r_[0, tp]) / pos
    return float((precision * recall_gain).sum())


@dataclass(frozen=True, slots=True)
class LeadTime:
    """At the largest threshold that catches ``recall`` of the failed episodes before
    their violation: the threshold, the recall reached, the steps from the first alarm
    to the violation (median and each caught episode's), and what it costs on successful
    episodes (alarmed pushes per episode, and the share with any alarm)."""

    recall: float
    threshold: float
    caught: float
    median_steps: float
    steps: tuple[int, ...]
    false_alarms_per_success: float
    successes_alarmed: float
    failed: int
    successes: int


def lead_time(scores: npt.ArrayLike, episode: npt.ArrayLike, to_violation: npt.ArrayLike,
              fails: npt.ArrayLike, succeeded: npt.ArrayLike, recall: float = 0.8
              ) -> LeadTime:
    """Scores of policy pushes with their episode id, steps to the violation, and whether
    the episode failed or succeeded (``testbed.monitor.labels.PolicyPushes``). A failed
    episode counts when the policy pushed in it at least once (else nothing could
    foresee it)."""
    if not 0.0 < recall <= 1.0:
        raise ValueError(f"recall must be in (0, 1], got {recall}")
    s = np.asarray(scores, dtype=np.float64)
    ep = np.asarray(episode)
    tv = np.asarray(to_violation, dtype=np.float64)
    fail, ok = np.asarray(fails, dtype=bool), np.asarray(succeeded, dtype=bool)
    failed_ids = np.unique(ep[fail])
    success_ids = np.unique(ep[ok])
    nan = float("nan")
    if failed_ids.size == 0:
        return LeadTime(recall, nan, nan, nan, (), nan, nan, 0, int(success_ids.size))
    peak = np.sort([s[ep == e].max() for e in failed_ids])
    # the largest peak that at least ``recall`` of the peaks reach
    threshold = float(peak[int(np.floor(peak.size * (1.0 - recall) + 1e-9))])
    leads = []
    for e in failed_ids:
        at = (ep == e) & (s >= threshold)
        if at.any():
            leads.append(int(tv[at].max()))  # the first alarm is the furthest from the end
    caught = len(leads) / failed_ids.size
    alarmed = ok & (s >= threshold)
    per_success = (alarmed.sum() / success_ids.size) if success_ids.size else nan
    share = (np.unique(ep[alarmed]).size / success_ids.size) if success_ids.size else nan
    return LeadTime(recall, threshold, float(caught),
                    float(np.median(leads)) if leads else nan, tuple(sorted(leads)),
                    float(per_success), float(share), int(failed_ids.size),
                    int(success_ids.size))


@dataclass(frozen=True, slots=True)
class ReliabilityBin:
    """Scores in [low, high): how many, their mean, how often the event happened, and
    that frequency's 95 % Wilson interval."""

    low: float
    high: float
    count: int
    mean_score: float
    frequency: float
    freq_low: float
    freq_high: float


def reliability(scores: npt.ArrayLike, labels: npt.ArrayLike,
                bins: int = RELIABILITY_BINS) -> tuple[list[ReliabilityBin], float]:
    """The reliability table of a score in [0, 1] claimed as a probability, and its
    expected calibration error (the count-weighted mean |mean score - frequency|)."""
    s, y = _checked(scores, labels)
    if s.size and (s.min() < 0.0 or s.max() > 1.0):
        raise ValueError("a reliability table needs scores in [0, 1]")
    edges = np.linspace(0.0, 1.0, bins + 1)
    which = np.clip(np.searchsorted(edges, s, side="right") - 1, 0, bins - 1)
    table: list[ReliabilityBin] = []
    gap = 0.0
    for b in range(bins):
        at = which == b
        n = int(at.sum())
        if n == 0:
            continue
        k = int(y[at].sum())
        ci = binomtest(k, n).proportion_ci(0.95, method="wilson")
        mean = float(s[at].mean())
        table.append(ReliabilityBin(float(edges[b]), float(edges[b + 1]), n, mean, k / n,
                                    float(ci.low), float(ci.high)))
        gap += n * abs(mean - k / n)
    return table, (gap / s.size if s.size else float("nan"))
