"""A failure alarm whose false-alarm rate has a bound: split conformal prediction on the
policy's successful episodes (as FAIL-Detect, 2025, and FIPER, 2025, calibrate theirs).

The unit is an episode. For a score (any signal, larger = more alarming), an episode's
peak is its largest score over the policy's pushes; the alarm fires on a push whose
score exceeds the threshold. Given the peaks m_1..m_n of n successful episodes, the
threshold is their k-th smallest, k = ceil((n + 1)(1 - alpha)) (``+inf`` while
k > n, i.e. n < 1/alpha - 1: too few episodes to promise anything, so the alarm stays
silent and whatever allocation asked for it falls back to its own rule).

**The guarantee.** If a new successful episode's peak is exchangeable with the n
calibration peaks, P(the alarm fires anywhere in it) <= alpha, and >= alpha - 1/(n + 1)
when peaks do not tie. Marginal: over the draw of the calibration episodes, not for
every calibration set.

**What breaks it.** Exchangeability. A policy that learns changes its signals' scale
(uncertainty falls as data comes in), so old episodes are not exchangeable with new
ones: the online alarm recalibrates on the last ``window`` successful episodes only,
trading the bound's slack (fewer episodes, a coarser quantile) for relevance. Episodes
that end because a person took the arm are not in the calibration set at all (neither
success nor failure by the labels), which biases it towards quiet episodes when people
intervene on high scores; the replay below measures the rate actually reached.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

__all__ = ["DEFAULT_WINDOW", "ConformalAlarm", "Replay", "check_alpha",
           "conformal_threshold", "episodes_needed", "replay_online", "replay_split"]

DEFAULT_WINDOW: Final = 200
"""Successful episodes the online alarm calibrates on (the latest ones)."""


def check_alpha(alpha: float) -> float:
    """``alpha`` as a float in (0, 1), else ValueError naming it."""
    a = float(alpha)
    if not 0.0 < a < 1.0 or math.isnan(a):
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    return a


def episodes_needed(alpha: float) -> int:
    """The fewest successful episodes for a finite threshold at ``alpha``."""
    return max(math.ceil(1.0 / check_alpha(alpha) - 1.0 - 1e-12), 1)


def conformal_threshold(peaks: npt.ArrayLike, alpha: float) -> float:
    """The k-th smallest of ``peaks``, k = ceil((n + 1)(1 - alpha)); ``inf`` if k > n."""
    a = check_alpha(alpha)
    m = np.sort(np.asarray(peaks, dtype=np.float64))
    if np.isnan(m).any():
        raise ValueError("episode peaks have NaN")
    k = math.ceil((m.size + 1) * (1.0 - a) - 1e-12)
    return float(m[k - 1]) if 1 <= k <= m.size else float("inf")


class ConformalAlarm:
    """The online alarm: a threshold from the last ``window`` successful episodes'
    peaks, recomputed each time one settles (:meth:`add`). Checkpointed with the run."""

    def __init__(self, alpha: float, window: int = DEFAULT_WINDOW) -> None:
        self.alpha: Final[float] = check_alpha(alpha)
        if window < episodes_needed(alpha):
            raise ValueError(f"window must hold at least {episodes_needed(alpha)} "
                             f"episodes for alpha {alpha}, got {window}")
        self.window: Final[int] = int(window)
        self._peaks: deque[float] = deque(maxlen=self.window)
        self.threshold = float("inf")

    @property
    def ready(self) -> bool:
        """Enough successful episodes for a finite threshold."""
        return math.isfinite(self.threshold)

    @property
    def calibrated_on(self) -> int:
        return len(self._peaks)

    def add(self, peak: float) -> None:
        """A successful episode settled with this peak score (``-inf``: no policy push)."""
        self._peaks.append(float(peak))
        self.threshold = conformal_threshold(np.fromiter(self._peaks, float), self.alpha)

    def fires(self, scores: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """Per score: above the threshold (never while not ready)."""
        return np.asarray(scores, dtype=np.float64) > self.threshold

    def state_dict(self) -> dict[str, Any]:
        """JSON-safe (a checkpoint's state.json): a peak of -inf (no policy push) is null."""
        return {"alpha": self.alpha, "window": self.window,
                "peaks": [p if math.isfinite(p) else None for p in self._peaks]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self._peaks = deque((-math.inf if p is None else float(p) for p in state["peaks"]),
                            maxlen=self.window)
        self.threshold = (conformal_threshold(np.fromiter(self._peaks, float), self.alpha)
                          if self._peaks else float("inf"))


@dataclass(frozen=True, slots=True)
class Replay:
    """A false-alarm rate measured by replay: the share of held-out successful episodes
    on which the alarm fired, its Monte-Carlo standard error, over how many episodes (and
    splits, for a split replay)."""

    alpha: float
    rate: float
    mc_error: float
    episodes: int
    splits: int

    @property
    def holds(self) -> bool:
        """The rate is within alpha plus twice its Monte-Carlo error."""
        return self.rate <= self.alpha + 2.0 * self.mc_error


def replay_split(peaks: npt.ArrayLike, alpha: float, *, splits: int = 1000,
                 seed: int = 0) -> Replay:
    """Exchangeable replay: ``splits`` times, calibrate on a random half of the
    successful episodes' peaks and count the alarms on the other half. NaN (0 splits)
    when a half is too small for a finite threshold (``episodes_needed``)."""
    m = np.asarray(peaks, dtype=np.float64)
    a = check_alpha(alpha)
    if m.size < 2:
        return Replay(a, float("nan"), float("nan"), int(m.size), 0)
    half = m.size // 2
    if half < episodes_needed(a):  # no finite threshold on a half: nothing to measure
        return Replay(a, float("nan"), float("nan"), int(m.size), 0)
    rng = np.random.default_rng(seed)
    rates = np.empty(splits)
    for i in range(splits):
        order = rng.permutation(m.size)
        tau = conformal_threshold(m[order[:half]], a)
        rates[i] = float(np.mean(m[order[half:]] > tau))
    return Replay(a, float(rates.mean()), float(rates.std(ddof=1) / math.sqrt(splits)),
                  int(m.size), splits)


def replay_online(peaks: npt.ArrayLike, alpha: float, window: int = DEFAULT_WINDOW
                  ) -> Replay:
    """As deployed: successful episodes in the order they settled, each judged by the
    threshold of the ``window`` before it (episodes before the alarm is ready are not
    counted). The error is the binomial standard error of the rate."""
    m = np.asarray(peaks, dtype=np.float64)
    alarm = ConformalAlarm(alpha, window)
    fired: list[bool] = []
    for p in m.tolist():
        if alarm.ready:
            fired.append(p > alarm.threshold)
        alarm.add(p)
    n = len(fired)
    if n == 0:
        return Replay(alarm.alpha, float("nan"), float("nan"), 0, 1)
    rate = float(np.mean(fired))
    return Replay(alarm.alpha, rate, math.sqrt(max(rate * (1 - rate), 1e-12) / n), n, 1)
