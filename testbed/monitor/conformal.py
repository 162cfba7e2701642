"""A failure alarm with a stated false-alarm guarantee: conformal thresholds on the peaks
of the policy's successful episodes with no intervention, and adaptive conformal
inference (ACI; Gibbs & Candes, 2021) for a policy whose scores drift.

The unit is an episode. For a score (any signal, larger = more alarming), an episode's
peak is its largest score over the policy's pushes; the alarm fires on a push whose
score exceeds the threshold. Given the peaks m_1..m_n of n calibration episodes and a
level a, the threshold is their k-th smallest, k = ceil((n + 1)(1 - a)): ``+inf`` while
k > n (a <= 0, or too few episodes: the alarm is silent), ``-inf`` when k <= 0 (a >= 1:
it fires on every push).

**Calibration set.** Successful episodes that no person touched (no teleop, no reset):
a success a person rescued ends well because of the person, and its peak is often the
score that called them, so it does not say what a success of the policy alone looks
like (issue 45, item 2). The latest ``window`` of them.

**Split** (``ConformalAlarm``, ``monitor.alarm = "split"``): a = alpha. If a new
untouched success's peak is exchangeable with the n calibration peaks, P(the alarm fires
in it) <= alpha (and >= alpha - 1/(n + 1) without ties), marginally over the calibration
draw. A learning policy's scores drift, so its episodes are not exchangeable, and then
nothing is promised: with peaks whose scale rises, the window's threshold lags and the
rate goes well above alpha (``tests/testbed/test_conformal_aci.py``).

**ACI** (``AdaptiveAlarm``, ``monitor.alarm = "aci"``, the default): the level moves with
what the alarm did, a_{t+1} = a_t + gamma (alpha - err_t), a_1 = alpha, where err_t is 1
when the alarm fired in the t-th untouched successful episode judged (one that ended
while the alarm was ready: at least ``episodes_needed(alpha)`` calibration peaks). Summed,
a_{T+1} = alpha + gamma sum_t (alpha - err_t), so the realised false-alarm rate of the T
judged episodes is exactly

    mean(err) = alpha + (alpha - a_{T+1}) / (gamma T),

deterministic, for *any* sequence of peaks (no exchangeability, no model of the drift).
The alarm cannot fire while the level in force is <= 0 (threshold +inf) and fires on
every push while it is >= 1 (-inf). With one episode at a time (Gibbs & Candes' setting,
and the replays here), an err_t = 1 lowers a from above 0, so a_t > -gamma (1 - alpha),
and a_t < 1 + gamma alpha the same way:

    alpha - (1 - alpha + gamma alpha) / (gamma T) <= mean(err)
                                                <= alpha + (alpha + gamma (1 - alpha)) / (gamma T),

the one-sided form of their |mean(err) - alpha| <= (max(a_1, 1 - a_1) + gamma) / (gamma T).
On a fleet of A arms, episodes overlap: an episode judged after the level went <= 0 may
have fired before, while it was above; at most A are in flight at once, so the bounds
hold with gamma replaced by A gamma in the numerators (``aci_bounds``). What the bound
says: the share of untouched successes the alarm fired on; not how it would have done on
the successes a person rescued (their counterfactual is not in the records).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any, ClassVar, Final, Literal

import numpy as np
import numpy.typing as npt

from testbed.monitor.false_alarms import AlarmRate, alarm_rate

__all__ = ["ALARMS", "DEFAULT_GAMMA", "DEFAULT_WINDOW", "AdaptiveAlarm", "Alarm",
           "AlarmKind", "ConformalAlarm", "Replay", "SplitCheck", "aci_bounds",
           "check_alpha", "check_gamma", "conformal_threshold", "episodes_needed",
           "level_threshold", "make_alarm", "replay_online", "replay_split"]

AlarmKind = Literal["aci", "split"]
ALARMS: Final[tuple[str, ...]] = ("aci", "split")
DEFAULT_WINDOW: Final = 200
"""Untouched successful episodes the alarm calibrates on (the latest ones)."""
DEFAULT_GAMMA: Final = 0.05
"""ACI's step: the bound's slack is about 1 / (gamma T) (T judged episodes: 0.024 above
alpha 0.05 after 80, one arm), a larger step follows a drift faster with a noisier level."""


def check_alpha(alpha: float) -> float:
    """``alpha`` as a float in (0, 1), else ValueError naming it."""
    a = float(alpha)
    if not 0.0 < a < 1.0 or math.isnan(a):
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    return a


def check_gamma(gamma: float) -> float:
    """ACI's step as a float in (0, 1], else ValueError naming it (0 is no adaptation
    and no bound; above 1 the level jumps past [0, 1] on one episode)."""
    g = float(gamma)
    if not 0.0 < g <= 1.0 or math.isnan(g):
        raise ValueError(f"gamma must be in (0, 1], got {gamma!r}")
    return g


def episodes_needed(alpha: float) -> int:
    """The fewest calibration episodes for a finite threshold at ``alpha``."""
    return max(math.ceil(1.0 / check_alpha(alpha) - 1.0 - 1e-12), 1)


def level_threshold(peaks: npt.ArrayLike, level: float) -> float:
    """The k-th smallest of ``peaks``, k = ceil((n + 1)(1 - level)), for any real level:
    ``inf`` if k > n (never fires), ``-inf`` if k < 1 (fires on every score)."""
    m = np.sort(np.asarray(peaks, dtype=np.float64))
    if np.isnan(m).any() or math.isnan(level):
        raise ValueError("episode peaks or the level have NaN")
    k = math.ceil((m.size + 1) * (1.0 - level) - 1e-12)
    if k < 1:
        return -math.inf
    return float(m[k - 1]) if k <= m.size else math.inf


def conformal_threshold(peaks: npt.ArrayLike, alpha: float) -> float:
    """The k-th smallest of ``peaks``, k = ceil((n + 1)(1 - alpha)); ``inf`` if k > n."""
    return level_threshold(peaks, check_alpha(alpha))


def aci_bounds(alpha: float, gamma: float, judged: int, arms: int = 1
               ) -> tuple[float, float]:
    """The (lowest, highest) realised false-alarm rate ACI allows over ``judged`` episodes
    with at most ``arms`` in flight at once (module docstring): deterministic."""
    a, g = check_alpha(alpha), check_gamma(gamma)
    if judged < 1:
        return -math.inf, math.inf
    return (a - (1.0 - a + arms * g * a) / (g * judged),
            a + (a + arms * g * (1.0 - a)) / (g * judged))


class ConformalAlarm:
    """The split alarm: a threshold from the last ``window`` untouched successful
    episodes' peaks at level alpha, recomputed each time one settles (:meth:`add`)."""

    kind: ClassVar[str] = "split"

    def __init__(self, alpha: float, window: int = DEFAULT_WINDOW) -> None:
        self.alpha: Final[float] = check_alpha(alpha)
        if window < episodes_needed(alpha):
            raise ValueError(f"window must hold at least {episodes_needed(alpha)} "
                             f"episodes for alpha {alpha}, got {window}")
        self.window: Final[int] = int(window)
        self._peaks: deque[float] = deque(maxlen=self.window)
        self.threshold = math.inf
        self.judged = 0
        """Episodes judged once ready (``add`` with ``fired`` given)."""
        self.fired = 0
        """Of them, those the alarm fired in."""

    @property
    def level(self) -> float:
        """The level the threshold is at (alpha: the split alarm does not adapt)."""
        return self.alpha

    @property
    def ready(self) -> bool:
        """Enough calibration episodes: the alarm decides (before: the fallback rule)."""
        return self.calibrated_on >= episodes_needed(self.alpha)

    @property
    def calibrated_on(self) -> int:
        return len(self._peaks)

    def _judge(self, fired: bool) -> None:
        """Count a judged episode (the split alarm's level does not move)."""
        self.judged += 1
        self.fired += bool(fired)

    def add(self, peak: float, fired: bool | None = None) -> None:
        """An untouched successful episode settled with this peak score (finite); with
        ``fired`` (whether the alarm fired in it), it is judged if the alarm was ready."""
        p = float(peak)
        if not math.isfinite(p):
            raise ValueError(f"an episode's peak must be finite, got {peak!r}")
        if fired is not None and self.ready:
            self._judge(fired)
        self._peaks.append(p)
        self.threshold = self._threshold()

    def _threshold(self) -> float:
        return (level_threshold(np.fromiter(self._peaks, float), self.level)
                if self.ready else math.inf)

    def fires(self, scores: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """Per score: above the threshold (never while not ready)."""
        s = np.asarray(scores, dtype=np.float64)
        return s > self.threshold if self.ready else np.zeros(s.shape, bool)

    def state_dict(self) -> dict[str, Any]:
        """JSON-safe (a checkpoint's state.json)."""
        return {"kind": self.kind, "alpha": self.alpha, "window": self.window,
                "peaks": list(self._peaks), "judged": self.judged, "fired": self.fired}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """A state of either kind, or a checkpoint's from before issue 45 (peaks only, a
        null for an episode without a policy push, which is dropped): the peaks calibrate,
        the counts start at 0 where the state has none."""
        self._peaks = deque((float(p) for p in state["peaks"] if p is not None),
                            maxlen=self.window)
        self.judged = int(state.get("judged", 0))
        self.fired = int(state.get("fired", 0))
        self.threshold = self._threshold()


class AdaptiveAlarm(ConformalAlarm):
    """ACI: the threshold at level ``a_t`` over the same window, ``a_t`` moved by
    ``gamma (alpha - err)`` after each judged episode (the guarantee: module docstring)."""

    kind: ClassVar[str] = "aci"

    def __init__(self, alpha: float, window: int = DEFAULT_WINDOW,
                 gamma: float = DEFAULT_GAMMA) -> None:
        super().__init__(alpha, window)
        self.gamma: Final[float] = check_gamma(gamma)
        self.a_t = self.alpha

    @property
    def level(self) -> float:
        return self.a_t

    def _judge(self, fired: bool) -> None:
        super()._judge(fired)
        self.a_t += self.gamma * (self.alpha - float(bool(fired)))

    def bounds(self, arms: int = 1) -> tuple[float, float]:
        """What ACI guarantees the realised rate of the episodes judged so far."""
        return aci_bounds(self.alpha, self.gamma, self.judged, arms)

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "gamma": self.gamma, "a_t": self.a_t}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """As the split alarm's; the level where the state has one (an ACI's), else
        alpha (a split alarm's state, or one from before issue 45)."""
        self.a_t = float(state.get("a_t", self.alpha))
        super().load_state_dict(state)


Alarm = ConformalAlarm
"""Either alarm (``AdaptiveAlarm`` is one)."""


def make_alarm(kind: str, alpha: float, window: int = DEFAULT_WINDOW,
               gamma: float = DEFAULT_GAMMA) -> ConformalAlarm:
    """The alarm ``monitor.alarm`` names."""
    if kind == "aci":
        return AdaptiveAlarm(alpha, window, gamma)
    if kind == "split":
        return ConformalAlarm(alpha, window)
    raise ValueError(f"alarm must be one of {', '.join(ALARMS)}, got {kind!r}")


@dataclass(frozen=True, slots=True)
class SplitCheck:
    """A sanity check of the threshold's arithmetic, not evidence: the share of held-out
    peaks above a random half's threshold, its Monte-Carlo error, the peaks and splits."""

    alpha: float
    rate: float
    mc_error: float
    episodes: int
    splits: int


def replay_split(peaks: npt.ArrayLike, alpha: float, *, splits: int = 1000,
                 seed: int = 0) -> SplitCheck:
    """``splits`` times, calibrate on a random half of ``peaks`` and count the alarms on
    the other half. The halves are exchangeable by construction (a random permutation of
    pooled peaks), so the rate is alpha up to the bound's slack whatever the peaks are:
    this **cannot fail**, checks only the arithmetic, and is no evidence that a live
    alarm keeps its bound. NaN (0 splits) when a half is too small for a threshold."""
    m = np.asarray(peaks, dtype=np.float64)
    a = check_alpha(alpha)
    half = m.size // 2
    if m.size < 2 or half < episodes_needed(a):
        return SplitCheck(a, math.nan, math.nan, int(m.size), 0)
    rng = np.random.default_rng(seed)
    rates = np.empty(splits)
    for i in range(splits):
        order = rng.permutation(m.size)
        tau = conformal_threshold(m[order[:half]], a)
        rates[i] = float(np.mean(m[order[half:]] > tau))
    return SplitCheck(a, float(rates.mean()), float(rates.std(ddof=1) / math.sqrt(splits)),
                      int(m.size), splits)


@dataclass(frozen=True, slots=True)
class Replay:
    """An alarm replayed on runs' untouched successful episodes in the order they ran:
    per run, the episodes judged and those it fired in; the pooled rate with its upper
    bound clustered by run (``rate``); ACI's deterministic bound per run, if ACI."""

    kind: str
    judged: tuple[int, ...]
    fired: tuple[int, ...]
    rate: AlarmRate
    guarantee: tuple[float, ...] = ()
    """Per run, the most ACI lets its rate be (``aci_bounds``, one arm); () for split."""

    @property
    def holds(self) -> bool:
        """The rate's one-sided upper bound (clustered by run) is at most alpha."""
        return self.rate.holds

    @property
    def within_guarantee(self) -> bool:
        """Every run's rate is within ACI's bound (always, by the theorem: a check)."""
        return all(f <= g * j + 1e-9 for f, j, g
                   in zip(self.fired, self.judged, self.guarantee, strict=True))


def replay_online(runs: list[npt.NDArray[np.float64]], alpha: float,
                  window: int = DEFAULT_WINDOW, *, kind: str = "aci",
                  gamma: float = DEFAULT_GAMMA) -> Replay:
    """As deployed, one alarm per run: each run's untouched successful episodes' peaks in
    the order they settled, each judged by the alarm as it stood before it (fired: its
    peak above the threshold), then calibrating it. Episodes before the alarm is ready are
    not judged."""
    judged, fired, guarantee = [], [], []
    for peaks in runs:
        alarm = make_alarm(kind, alpha, window, gamma)
        for p in np.asarray(peaks, dtype=np.float64).tolist():
            alarm.add(p, bool(alarm.fires([p])[0]))
        judged.append(alarm.judged)
        fired.append(alarm.fired)
        if isinstance(alarm, AdaptiveAlarm):
            guarantee.append(alarm.bounds()[1])
    return Replay(kind, tuple(judged), tuple(fired), alarm_rate(fired, judged, alpha),
                  tuple(guarantee))
