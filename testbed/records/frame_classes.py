"""Every frame's class and its episode's outcome: who acted, and how it ended.

Why: learning by class (issue 30, ``learning.weighting = "intervention"``) trains on the
robot's own pushes as well as the humans' labels, weighted by what each kind teaches
(Sirius, Liu et al. RSS 2023): a push among the robot's last ``k`` steps before a person
took the arm led there (pre-intervention, down-weighted), a push in an episode that
succeeded is worth keeping, one in an episode that ended in a violation is not. Both need
what only later steps say, so a class is *derived* from the data store's frames, never
written into them (the store is append-only and a frame is written at its step): one
set of rules here, run the same way live (the fleet loop's :class:`LabelFeed`), on
resume (``store.replay``) and for exports (:func:`classify`).

Rules, per arm, over its frames in step order (``testbed.core.types`` FrameClass,
EpisodeOutcome):

* class: mode autonomous with a push: ROBOT; teleop with a push: TELEOP; reset: RESET;
  anything else (idle, fault, refused, a teleop step the human let pass): NONE.
* an episode ends at a frame with a success (SUCCESS) or a violation (VIOLATION; the
  idle, reset and fault frames that follow it, while the cube is out, belong to it), or
  at the frame before the goal changes (the next observed frame's goal differs):
  GOAL_CHANGE, or UNKNOWN when frames not observed (a fault) lie between the two goals
  (a success may have been hidden), or OPEN when a resume lies between them (the world
  was started anew). An episode still running when the records stop is OPEN.
* a takeover is a frame with a human after one without (a teleop or a hard reset): the
  arm's ROBOT frames of the same episode in steps ``t - k .. t - 1`` become
  PRE_INTERVENTION. A window is cut at step 0 and at the episode's start; it crosses a
  resume when the episode goes on across it (the same goal after it).

Settling: a frame's class and outcome are final when its episode ends (a goal change is
seen one observed frame later). :class:`ClassTracker` hands each episode's frames out
then, arms in index order within a step, so a replay of the same steps hands out the
same frames in the same order.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Final, Protocol

import numpy as np

from testbed.core.types import DEFAULT_PRE_STEPS, EpisodeOutcome, FrameClass, Mode

__all__ = ["DEFAULT_PRE_STEPS", "ClassTracker", "Classes", "LabelFeed", "Settled",
           "classify", "frame_class"]

_MODE_CODE: Final = {m: i for i, m in enumerate(m.value for m in Mode)}
_AUTONOMOUS: Final = _MODE_CODE[Mode.AUTONOMOUS.value]
_TELEOP: Final = _MODE_CODE[Mode.TELEOP.value]
_RESET: Final = _MODE_CODE[Mode.RESET.value]
_AFTER_VIOLATION: Final = frozenset(_MODE_CODE[m.value]
                                    for m in (Mode.IDLE, Mode.RESET, Mode.FAULT))
"""Modes that keep a violated episode going: the cube is out until the reset ends."""
GOAL_TOLERANCE: Final = 1e-6


def frame_class(frame: Any) -> FrameClass:
    """The class of one frame before any pre-intervention window (see the module)."""
    mode, action = int(frame["mode"]), int(frame["action"])
    if mode == _AUTONOMOUS and action >= 0:
        return FrameClass.ROBOT
    if mode == _TELEOP and action >= 0:
        return FrameClass.TELEOP
    if mode == _RESET:
        return FrameClass.RESET
    return FrameClass.NONE


@dataclass(frozen=True)
class Settled:
    """One arm's finished episode (or its open end): its frames (the store's rows, in
    step order), each one's class, the episode's outcome and index (per arm, from 0)."""

    frames: np.ndarray
    classes: np.ndarray
    outcomes: np.ndarray
    episodes: np.ndarray


@dataclass
class _Arm:
    rows: list[np.ndarray] = field(default_factory=list)
    classes: list[int] = field(default_factory=list)
    episode: int = 0
    violated: bool = False
    goal: np.ndarray | None = None
    """The goal of the episode's last observed frame (None: none observed yet)."""
    goal_session: int = -1
    gap: bool = False
    """Frames not observed since ``goal`` was seen."""
    human: int = -1
    """The human on the arm's last frame (-1: none)."""


class ClassTracker:
    """The rules above, one step at a time: :meth:`push` each step's frames (one per
    arm, in the store's arm order); it returns the episodes that ended."""

    def __init__(self, num_arms: int, pre_steps: int) -> None:
        if pre_steps < 0:
            raise ValueError(f"pre_steps must be >= 0, got {pre_steps}")
        self.num_arms = int(num_arms)
        self.pre_steps = int(pre_steps)
        self._arms = [_Arm() for _ in range(self.num_arms)]

    def push(self, frames: np.ndarray) -> list[Settled]:
        """Take one step's frames; return the episodes (per arm) that this step ended."""
        if len(frames) != self.num_arms:
            raise ValueError(f"a step is {self.num_arms} frames, got {len(frames)}")
        out: list[Settled] = []
        for i in range(self.num_arms):
            out.extend(self._take(self._arms[i], frames[i : i + 1]))
        return out

    def flush(self) -> list[Settled]:
        """The episodes still running (outcome OPEN, or VIOLATION for one whose cube was
        out when the records stop); the tracker is then empty."""
        out = []
        for arm in self._arms:
            if arm.rows:
                out.append(self._settle(arm, EpisodeOutcome.VIOLATION if arm.violated
                                        else EpisodeOutcome.OPEN))
        return out

    def _take(self, arm: _Arm, row: np.ndarray) -> list[Settled]:
        f = row[0]
        out: list[Settled] = []
        observed, session = bool(f["observed"]), int(f["session"])
        if arm.violated:  # a reset confirmed early shows the new goal: still the violation's
            if int(f["mode"]) not in _AFTER_VIOLATION:
                out.append(self._settle(arm, EpisodeOutcome.VIOLATION))
        elif observed and arm.goal is not None and arm.rows and not np.allclose(
                f["goal"], arm.goal, atol=GOAL_TOLERANCE, equal_nan=False):
            ending = (EpisodeOutcome.OPEN if session != arm.goal_session
                      else EpisodeOutcome.UNKNOWN if arm.gap else EpisodeOutcome.GOAL_CHANGE)
            out.append(self._settle(arm, ending))
        cls = frame_class(f)
        human = int(f["human"])
        if human >= 0 > arm.human:  # a takeover: the robot's last k pushes led here
            t = int(f["t"])
            for j in range(len(arm.rows) - 1, -1, -1):
                if int(arm.rows[j]["t"][0]) < t - self.pre_steps:
                    break
                if arm.classes[j] == FrameClass.ROBOT:
                    arm.classes[j] = FrameClass.PRE_INTERVENTION
        arm.human = human
        arm.rows.append(row.copy())
        arm.classes.append(int(cls))
        if observed:
            arm.goal, arm.goal_session, arm.gap = np.array(f["goal"]), session, False
        else:
            arm.gap = True
        if bool(f["success"]):
            out.append(self._settle(arm, EpisodeOutcome.SUCCESS))
        elif bool(f["violation"]):
            arm.violated = True
        return out

    @staticmethod
    def _settle(arm: _Arm, outcome: EpisodeOutcome) -> Settled:
        n = len(arm.rows)
        settled = Settled(frames=np.concatenate(arm.rows),
                          classes=np.asarray(arm.classes, dtype=np.int8),
                          outcomes=np.full(n, int(outcome), dtype=np.int8),
                          episodes=np.full(n, arm.episode, dtype=np.int32))
        arm.rows, arm.classes = [], []
        arm.episode += 1
        arm.violated = False
        arm.goal, arm.gap = None, False
        return settled


@dataclass(frozen=True)
class Classes:
    """Per frame of a run (aligned with the frames given to :func:`classify`): its
    class, its episode's outcome, and the episode's index on its arm."""

    classes: np.ndarray
    outcomes: np.ndarray
    episodes: np.ndarray

    def counts(self) -> dict[str, dict[str, int]]:
        """How many frames of each class and of each outcome (names as keys)."""
        return {
            "classes": {c.name.lower(): int(np.count_nonzero(self.classes == c))
                        for c in FrameClass},
            "outcomes": {o.name.lower(): int(np.count_nonzero(self.outcomes == o))
                         for o in EpisodeOutcome},
        }


def classify(frames: np.ndarray, num_arms: int, pre_steps: int = DEFAULT_PRE_STEPS
             ) -> Classes:
    """Every frame's class, outcome and episode: ``frames`` step-major, ``num_arms`` a
    step (as ``RunData.frames()`` gives them); the episodes running at the end are OPEN."""
    n = len(frames)
    if n % max(num_arms, 1):
        raise ValueError(f"{n} frames are not whole steps of {num_arms} arms")
    classes = np.full(n, int(FrameClass.NONE), dtype=np.int8)
    outcomes = np.zeros(n, dtype=np.int8)
    episodes = np.zeros(n, dtype=np.int32)
    if n == 0:
        return Classes(classes, outcomes, episodes)
    t0 = int(frames["t"][0])
    tracker = ClassTracker(num_arms, pre_steps)
    settled: list[Settled] = []
    for s in range(n // num_arms):
        settled.extend(tracker.push(frames[s * num_arms : (s + 1) * num_arms]))
    settled.extend(tracker.flush())
    for part in settled:
        at = (part.frames["t"].astype(np.int64) - t0) * num_arms + part.frames["arm"]
        classes[at], outcomes[at], episodes[at] = part.classes, part.outcomes, part.episodes
    return Classes(classes, outcomes, episodes)


# ------------------------------------------------------------------ the learner's feed
class RobotSink(Protocol):
    def add_robot(self, images: np.ndarray, actions: np.ndarray, classes: np.ndarray,
                  outcomes: np.ndarray) -> None: ...


class LabelFeed:
    """The robot's own pushes for a learner that learns from them, as their episodes end
    (``Learner.add_robot``): ROBOT and PRE_INTERVENTION frames with their outcome. The
    fleet loop pushes each logged step; a resume rebuilds the pending episodes with
    :meth:`catch_up` (the replay gave the learner what had ended)."""

    def __init__(self, num_arms: int, pre_steps: int) -> None:
        self.tracker = ClassTracker(num_arms, pre_steps)

    def step(self, sink: RobotSink, frames: np.ndarray) -> None:
        """One logged step: give ``sink`` the robot pushes of the episodes it ended."""
        for part in self.tracker.push(frames):
            robot = (np.isin(part.classes, (FrameClass.ROBOT, FrameClass.PRE_INTERVENTION))
                     & (part.frames["action"] >= 0))
            if robot.any():
                sink.add_robot(part.frames["image"][robot],
                               part.frames["action"][robot].astype(np.int64),
                               part.classes[robot], part.outcomes[robot])

    def catch_up(self, steps: Iterable[np.ndarray]) -> None:
        """Push steps already given to the learner (a resume): the state, not the data."""
        for frames in steps:
            self.tracker.push(frames)
