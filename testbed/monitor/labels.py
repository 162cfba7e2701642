"""The policy's own pushes of a run, each with what came after it: the labels a failure
predictor is scored against.

Why from the frame classes: whether a push led to a failure is only known later (its
episode's end), and ``testbed.records.frame_classes`` already settles every frame's
episode and outcome, the same way live, on resume and for exports. A push here is a
frame of class ROBOT or PRE_INTERVENTION (mode autonomous with a push: what the monitor
watches); teleop pushes and resets are the people's, not predictions' business.

Labels per push, on its arm:

* ``to_violation``: steps from the push to its episode's violation (0: this push took
  the cube out), ``inf`` when the episode did not end in one;
* "a violation within k steps": ``to_violation < k``; known when the episode ended
  (success, violation, goal change) or the arm's records go on k - 1 steps past it;
  unknown (masked out) for the last pushes of an episode the records cut;
* "this episode fails": the episode ended in a violation (the hard reset a person must
  do). Episodes that ended otherwise than success or violation (a goal change after the
  50-push cap, a fault that hid the end, the records' end) are neither failed nor
  successful for the false-alarm count.

What the labels cannot see: a person who took the arm because a signal was high may have
prevented the violation it foresaw (the label then says "no violation"); a monitor that
calls people early looks worse than it is by exactly what it prevented. Scores on runs
of an algorithm that intervenes rarely (``bc``: resets only) are the cleanest.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Final

import numpy as np
import numpy.typing as npt

from testbed.core.types import EpisodeOutcome, FrameClass

__all__ = ["POLICY_CLASSES", "PolicyPushes", "episode_ids", "policy_pushes"]

POLICY_CLASSES: Final = (int(FrameClass.ROBOT), int(FrameClass.PRE_INTERVENTION))
"""The frame classes of the policy's own pushes."""
_SETTLED = (int(EpisodeOutcome.SUCCESS), int(EpisodeOutcome.VIOLATION),
            int(EpisodeOutcome.GOAL_CHANGE))


@dataclass(frozen=True)
class PolicyPushes:
    """One run's policy pushes (arrays aligned, in step order): where, the labels, the
    signals' scores at the push (NaN where a signal was not computed)."""

    t: npt.NDArray[np.int64]
    arm: npt.NDArray[np.int64]
    episode: npt.NDArray[np.int64]
    """Unique per (arm, episode) in the run."""
    outcome: npt.NDArray[np.int8]
    """The episode's ``EpisodeOutcome``."""
    to_violation: npt.NDArray[np.float64]
    horizon: npt.NDArray[np.float64]
    """How many steps after the push the labels can see: ``inf`` when the episode
    settled, else the arm's last recorded step - t + 1."""
    scores: dict[str, npt.NDArray[np.float64]] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.t.size)

    def within(self, k: int) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
        """(label "a violation within ``k`` steps", known): unknown pushes are masked."""
        if k < 1:
            raise ValueError(f"the horizon k must be >= 1, got {k}")
        label = self.to_violation < k
        return label, label | (self.horizon >= k)

    @property
    def fails(self) -> npt.NDArray[np.bool_]:
        """The push's episode ended in a violation."""
        return self.outcome == int(EpisodeOutcome.VIOLATION)

    @property
    def succeeded(self) -> npt.NDArray[np.bool_]:
        """The push's episode ended in a success."""
        return self.outcome == int(EpisodeOutcome.SUCCESS)

    @property
    def settled(self) -> npt.NDArray[np.bool_]:
        """The episode's end is known (success, violation or goal change)."""
        return np.isin(self.outcome, _SETTLED)

    def episode_max(self, name: str, outcome: EpisodeOutcome
                    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
        """(episode ids, the largest ``name`` score of each) over the episodes that ended
        in ``outcome``, in order of their first push; a score's NaN pushes are left out."""
        s = self.scores[name]
        pick = (self.outcome == int(outcome)) & ~np.isnan(s)
        ids, first = np.unique(self.episode[pick], return_index=True)
        order = np.argsort(first, kind="stable")
        maxima = np.full(ids.size, -np.inf)
        np.maximum.at(maxima, np.searchsorted(ids, self.episode[pick]), s[pick])
        return ids[order], maxima[order]


def episode_ids(frames: np.ndarray, episodes: np.ndarray) -> npt.NDArray[np.int64]:
    """Each frame's episode as one id per (arm, episode) in the run (``PolicyPushes.episode``)."""
    span = int(episodes.max()) + 1 if len(frames) else 1
    return frames["arm"].astype(np.int64) * span + episodes.astype(np.int64)


def policy_pushes(frames: np.ndarray, classes: np.ndarray, outcomes: np.ndarray,
                  episodes: np.ndarray, scores: Mapping[str, npt.ArrayLike]
                  ) -> PolicyPushes:
    """The policy pushes among ``frames`` (step-major, each with ``t``, ``arm`` and
    ``violation``), with the classes, outcomes and episodes of
    ``testbed.records.frame_classes.classify`` and per-frame ``scores`` (NaN: none)."""
    n = len(frames)
    for name, values in scores.items():
        if np.shape(values) != (n,):
            raise ValueError(f"score {name!r} has shape {np.shape(values)}, "
                             f"not one value per frame ({n})")
    t = frames["t"].astype(np.int64)
    arm = frames["arm"].astype(np.int64)
    episode = episode_ids(frames, episodes)
    # the step of each episode's violation (the frame that took the cube out)
    violating = np.asarray(frames["violation"], dtype=bool)
    ended_at = dict(zip(episode[violating].tolist(), t[violating].tolist(), strict=True))
    last_t = {a: int(t[arm == a].max()) for a in np.unique(arm).tolist()}
    pick = np.isin(classes, POLICY_CLASSES)
    pt, parm, pep = t[pick], arm[pick], episode[pick]
    pout = np.asarray(outcomes)[pick].astype(np.int8)
    to_v = np.array([ended_at.get(e, np.inf) for e in pep.tolist()], dtype=np.float64)
    to_v = to_v - pt
    settled = np.isin(pout, _SETTLED)
    horizon = np.where(settled, np.inf,
                       np.array([last_t[a] for a in parm.tolist()], dtype=np.float64)
                       - pt + 1)
    return PolicyPushes(pt, parm, pep, pout, to_v, horizon,
                        {k: np.asarray(v, dtype=np.float64)[pick] for k, v in scores.items()})
