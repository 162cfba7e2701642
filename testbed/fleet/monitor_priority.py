"""Allocation by the failure monitor (issue 36, item 4): a person where the calibrated
alarm fires, the arm most likely to fail first; arms the monitor trusts are left alone.

Key (c, a, s, u, r), larger first (the allocator's rules, docs/notes/core.md):

* c = 1 for a violating arm (its hard reset comes first, as in every algorithm);
* a = 1 where the alarm fires: the arm's score (``monitor.score``) is above the
  conformal threshold of the last ``monitor.window`` untouched successful episodes'
  peaks (``testbed.monitor.conformal``: ACI by default, ``monitor.alarm``), so the share
  of untouched successful episodes it fires in stays within ACI's stated bound of
  ``monitor.alpha`` (the split alarm's: at most alpha while its peaks stay exchangeable);
* s = that score on an alarmed arm (the ranking by predicted failure), else 0;
* u, r: C.U.R.'s thresholded uncertainty and risk, used only **until the alarm is ready**
  (fewer than 1/alpha - 1 untouched successful episodes): the fleet then runs as
  C.U.R. without its initial period. Once ready, u and r are 0: an arm whose score is
  under the threshold gets no person, whatever its uncertainty.

The alarm learns from the fleet's own episodes, arm by arm, as the loop reports each
step (``observe``): an episode's peak is its largest score over the policy's pushes
(autonomous with a push); a success no person touched (no teleop or reset in it) adds the
peak to the calibration and, once the alarm is ready, is judged (did the alarm fire at
one of its policy pushes: ACI's err); a success a person touched, a violation or a new
goal drops it (a person's rescue would calibrate on the score that called them). The
same rules as ``testbed.records.frame_classes`` (one episode ends at a success, a
violation, whose idle, reset and fault frames after it still belong to it, or a goal
change), so ``testbed/results/report_alarm.py`` reads the same episodes from the rows.

Scores: any learned signal by name; ``fail_head``: the failure head of ``monitor.head``
(``testbed/monitor/failure_head.py``: P(a violation within k steps) from the policy's
trunk features and its signals, fitted by ``testbed report`` on earlier runs); or
``ood_u``: the smaller of ``ood`` and the
uncertainty, each over its median among the last ``REFERENCE`` values the policy's pushes
had (FIPER's conjunction: high only where the image is unfamiliar *and* the action
uncertain). Each over its median, not its percentile rank: a rank stops at 1, so every
long episode's peak would be 1 and the conformal threshold too, an alarm that can never
fire (the first twin trial of the monitor showed it).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import Any, Final

import numpy as np

from testbed.core.types import Mode
from testbed.fleet.priorities import FloatArray, OrderedPriority, PrioritySignals, check_t
from testbed.monitor.conformal import DEFAULT_GAMMA, make_alarm
from testbed.monitor.failure_head import FailureHead
from testbed.records.store import MODES

__all__ = ["COMBINED", "MONITOR_READS", "REFERENCE", "SCALE_FLOOR", "MonitorPriority",
           "both_high"]

COMBINED: Final = {"ood_u": ("ood", "uncertainty")}
"""Scores made of two signals (both must be high)."""
MONITOR_READS: Final = frozenset({"uncertainty", "risk", "novelty", "ood"})
"""What the monitor algorithm may read (``AlgorithmSpec.reads``: the learner trains the
policy and the safety critic for it; the goal critic's risk would need its training too)."""
SCALE_FLOOR: Final = 1e-6
"""A median below this (a signal that is almost always 0) scales by this instead."""
REFERENCE: Final = 2000
"""Policy-push values whose median scales each part of a combined score (the latest)."""
_AUTONOMOUS: Final = MODES.index(Mode.AUTONOMOUS.value)
_TOUCHED: Final = frozenset(MODES.index(m.value) for m in (Mode.TELEOP, Mode.RESET))
"""Modes in which a person has the arm: its episode is touched."""
_AFTER_VIOLATION: Final = frozenset(MODES.index(m.value)
                                    for m in (Mode.IDLE, Mode.RESET, Mode.FAULT))
"""Modes that keep a violated episode going (``testbed.records.frame_classes``)."""


def both_high(parts: Sequence[FloatArray], references: Sequence[FloatArray]) -> FloatArray:
    """FIPER's conjunction as one score: the smaller of the parts, each over the median of
    its reference (high only where every part is). Live, the references are the latest
    policy pushes; ``testbed/results/prediction_runs.py`` scores a run with its own."""
    return np.minimum.reduce([v / max(float(np.median(ref)), SCALE_FLOOR)
                              for v, ref in zip(parts, references, strict=True)])


class MonitorPriority:
    """The monitor's keys; ``observe`` after every step (the loop does)."""

    names: tuple[str, ...] = ("c", "a", "s", "u", "r")

    @classmethod
    def reads_of(cls, score: str) -> frozenset[str]:
        """The learned signals it reads: the score's (a head's: any it may), and C.U.R.'s
        for before the alarm."""
        if score == "fail_head":
            return MONITOR_READS
        return frozenset({*COMBINED.get(score, (score,)), "uncertainty", "risk"})

    def __init__(self, num_robots: int, *, score: str, alpha: float, window: int,
                 u_hat: float, r_hat: float, head: FailureHead | None = None,
                 alarm: str = "aci", gamma: float = DEFAULT_GAMMA) -> None:
        if (score == "fail_head") != (head is not None):
            raise ValueError('a failure head is given with score = "fail_head", and only then')
        self.num_robots: Final[int] = num_robots
        self.score_name: Final[str] = score
        self.head = head
        self.reads: frozenset[str] = MONITOR_READS
        """Every signal it may watch, read each step whatever the score (so ``reads`` is
        the registry's, exactly: ``tests/testbed/test_train_parts.py``)."""
        self._cur = OrderedPriority("ur", num_robots, u_hat=u_hat, r_hat=r_hat)
        """C.U.R.'s thresholded (u, r), the keys until the alarm is ready."""
        self.alarm = make_alarm(alarm, alpha, window, gamma)
        self._peak = np.full(num_robots, -math.inf)
        self._touched = np.zeros(num_robots, bool)
        """A person had the arm in its current episode."""
        self._fired = np.zeros(num_robots, bool)
        """The alarm fired at a policy push of the arm's current episode."""
        self._violated = np.zeros(num_robots, bool)
        """The arm's episode ended in a violation; its reset is still the episode's."""
        self._alarmed = np.zeros(num_robots, bool)
        """The last keys' a (the alarm fired for the arm)."""
        self._goal = np.full((num_robots, 2), np.nan)
        self._last = np.zeros(num_robots)
        self._raw: dict[str, FloatArray] = {}
        self._reference: dict[str, deque[float]] = {
            name: deque(maxlen=REFERENCE) for name in COMBINED.get(score, ())}

    # ---- the score -----------------------------------------------------------------
    def scores(self, s: PrioritySignals) -> FloatArray:
        """Each arm's score at this step (no state changes)."""
        n = self.num_robots
        if self.head is not None:
            return self.head.score({name: s.signal(name, n) for name in self.head.inputs},
                                   s.features_array(n) if self.head.features else None)
        parts = COMBINED.get(self.score_name)
        if parts is None:
            return s.signal(self.score_name, n)
        if not all(self._reference[name] for name in parts):
            return np.zeros(n)
        return both_high([s.signal(name, n) for name in parts],
                         [np.fromiter(self._reference[name], float) for name in parts])

    def keys(self, s: PrioritySignals) -> FloatArray:
        n = self.num_robots
        check_t(s.t)
        viol = s.violating_array(n)
        for name in sorted(self.reads):  # all present and finite, whatever the score
            s.signal(name, n)
        score = self.scores(s)
        self._last = score
        self._raw = {name: s.signal(name, n) for name in self._reference}
        keys = np.zeros((n, 5))
        keys[:, 0] = viol
        if self.alarm.ready:
            fired = self.alarm.fires(score) & ~viol
            keys[fired, 1] = 1.0
            keys[fired, 2] = score[fired]
        else:
            keys[:, 3:] = self._cur.keys(s)
        keys[s.faulted_array(n)] = 0.0
        self._alarmed = keys[:, 1] > 0
        return keys

    def row_fields(self, robot: int) -> dict[str, float]:
        """What the step's row keeps of the alarm for an arm (its ``monitor``): the score
        and, once the alarm is ready, its level (ACI's a_t; alpha for split) and its
        threshold where finite (ACI's is +inf while a_t <= 0, -inf from 1)."""
        out = {"alarm_score": float(self._last[robot])}
        if self.alarm.ready:
            out["alarm_level"] = self.alarm.level
            if math.isfinite(self.alarm.threshold):
                out["alarm_threshold"] = self.alarm.threshold
        return out

    # ---- learning from the fleet's episodes ----------------------------------------------
    def observe(self, frames: np.ndarray) -> None:
        """The step's frames (the data store's, one per arm): peaks, who touched each
        episode, episode ends, the combined score's reference. The successes of a step
        reach the alarm after every arm's frame, judged by whether it was ready at the
        step's keys (what the rows say: ``alarm_level``)."""
        ready = self.alarm.ready
        settled: list[tuple[float, bool]] = []
        for a in range(self.num_robots):
            f = frames[a]
            if not bool(f["observed"]):
                continue
            mode = int(f["mode"])
            if self._violated[a]:
                if mode in _AFTER_VIOLATION:
                    continue
                self._violated[a] = False
            goal = np.asarray(f["goal"], dtype=float)
            if not np.isnan(self._goal[a]).any() and not np.allclose(goal, self._goal[a]):
                self._restart(a)  # a new goal without a success: dropped
            self._goal[a] = goal
            self._touched[a] |= mode in _TOUCHED
            if mode == _AUTONOMOUS and int(f["action"]) >= 0:
                self._peak[a] = max(self._peak[a], float(self._last[a]))
                self._fired[a] |= bool(self._alarmed[a])
                for name, ref in self._reference.items():
                    ref.append(float(self._raw[name][a]))
            if bool(f["success"]):
                if math.isfinite(self._peak[a]) and not self._touched[a]:
                    settled.append((float(self._peak[a]), bool(self._fired[a])))
                self._restart(a)
            elif bool(f["violation"]):
                self._restart(a)
                self._violated[a] = True
        for peak, fired in settled:
            self.alarm.add(peak, fired if ready else None)

    def _restart(self, a: int) -> None:
        """Arm ``a``'s episode ended: a new one has no peak, no person, no alarm yet."""
        self._peak[a] = -math.inf
        self._touched[a] = self._fired[a] = False

    def state_dict(self) -> dict[str, Any]:
        """JSON-safe: no peak (-inf) and no goal seen yet (NaN) are null."""
        return {"alarm": self.alarm.state_dict(),
                "peak": [p if math.isfinite(p) else None for p in self._peak.tolist()],
                "touched": self._touched.tolist(), "fired": self._fired.tolist(),
                "violated": self._violated.tolist(), "alarmed": self._alarmed.tolist(),
                "goal": [None if np.isnan(g).any() else g.tolist() for g in self._goal],
                "last": self._last.tolist(),
                "raw": {k: v.tolist() for k, v in self._raw.items()},
                "reference": {k: list(v) for k, v in self._reference.items()}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """A state of ``state_dict``, or one a run before issue 45 kept (the alarm's peaks
        calibrate the configured alarm; the episodes running then count as untouched)."""
        self.alarm.load_state_dict(state["alarm"])
        self._peak = np.array([-math.inf if p is None else p for p in state["peak"]])
        n = self.num_robots  # a checkpoint from before issue 45 has none of these four
        for name in ("touched", "fired", "violated", "alarmed"):
            setattr(self, f"_{name}", np.array(state.get(name, [False] * n), dtype=bool))
        self._goal = np.array([[np.nan, np.nan] if g is None else g for g in state["goal"]],
                              dtype=float)
        self._last = np.asarray(state["last"], dtype=float)
        self._raw = {k: np.asarray(v, dtype=float) for k, v in state["raw"].items()}
        for k, v in state["reference"].items():
            self._reference[k] = deque((float(x) for x in v), maxlen=REFERENCE)
