"""Every exported frame's class, its episode's outcome and that episode's index.

Why apart: an export cuts a run into *its* episodes (one arm, one goal; a hard reset's
end and a resume start a new one), while the classes (``testbed.records.frame_classes``)
have their own episodes (a violated episode keeps its idle wait and reset, and goes on
across a resume that left the goal alone). So each frame carries three columns, all
from the same rules as the learner and the report use (``testbed.records.run_classes``,
the run's own ``k``):

* ``frame_class``: ``FrameClass`` (0 demo, 1 robot, 2 teleop, 3 reset, 4
  pre-intervention, 5 none);
* ``episode_outcome``: ``EpisodeOutcome`` of the frame's class episode (0 open, 1
  success, 2 violation, 3 goal change, 4 unknown);
* ``class_episode``: that episode's index on its arm (from 0; a demonstration: its
  chain's index in its file), so ``(source_index, arm, class_episode)`` names it.

The offline demonstrations are all DEMO; a chain's outcome is its last push's (success,
violation, else open). An export written before these columns existed reads back with
them derived from its own columns (``derive``) at ``DEFAULT_PRE_STEPS``, and says so.

Nothing here imports torch, pyarrow or PyAV: numpy alone.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from testbed.core.types import EpisodeOutcome, FrameClass, Mode
from testbed.records.frame_classes import DEFAULT_PRE_STEPS, classify
from testbed.records.run_classes import LABEL_DTYPE, RunClasses
from testbed.records.store import MODES

CLASS_COLUMNS: Final = ("frame_class", "episode_outcome", "class_episode")
CLASS_NAMES: Final[list[str]] = [c.name.lower() for c in FrameClass]
"""``frame_class`` code -> name (LeRobot's feature ``names``)."""
OUTCOME_NAMES: Final[list[str]] = [o.name.lower() for o in EpisodeOutcome]
"""``episode_outcome`` code -> name."""
_FAULT_CODE: Final = MODES.index(Mode.FAULT.value)
"""A step missing from an export reads as a fault (nothing seen)."""


def codes() -> dict[str, dict[str, str]]:
    """What the codes mean, for meta/testbed.json and an npz's ``meta``."""
    return {"frame_class": {str(int(c)): c.name.lower() for c in FrameClass},
            "episode_outcome": {str(int(o)): o.name.lower() for o in EpisodeOutcome}}


def of_run(rc: RunClasses, arm: int) -> dict[str, np.ndarray]:
    """One arm's class columns, in step order (as ``run_episodes`` slices the store)."""
    n = len(rc.robots)
    c = rc.classes
    return {"frame_class": c.classes[arm::n].astype(np.int64),
            "episode_outcome": c.outcomes[arm::n].astype(np.int64),
            "class_episode": c.episodes[arm::n].astype(np.int64)}


def demo_outcome(success: np.ndarray, violation: np.ndarray) -> EpisodeOutcome:
    """A demonstration chain's outcome: its last push's success or violation, else open
    (the collector stopped it)."""
    if len(success) and bool(success[-1]):
        return EpisodeOutcome.SUCCESS
    if len(violation) and bool(violation[-1]):
        return EpisodeOutcome.VIOLATION
    return EpisodeOutcome.OPEN


def of_demo(n: int, outcome: EpisodeOutcome, chain: int) -> dict[str, np.ndarray]:
    """A demonstration episode's ``n`` frames: DEMO, its chain's outcome and index."""
    return {"frame_class": np.full(n, int(FrameClass.DEMO), np.int64),
            "episode_outcome": np.full(n, int(outcome), np.int64),
            "class_episode": np.full(n, chain, np.int64)}


# ----------------------------------------------------------------- older exports
def derive(columns: dict[str, np.ndarray], demo: np.ndarray,
           episode_index: np.ndarray) -> dict[str, np.ndarray]:
    """The class columns of an export that lacks them, from its own columns: each
    run's frames (``source_index``) put back step-major and classified at
    ``DEFAULT_PRE_STEPS`` (the run's own k is not in the export); ``demo`` frames are
    DEMO, each exported episode a chain (its outcome from its frames' flags)."""
    n = len(demo)
    out = {name: np.zeros(n, np.int64) for name in CLASS_COLUMNS}
    src, arm, step = (columns[k].astype(np.int64) for k in ("source_index", "arm", "step"))
    for s in np.unique(src[~demo]):
        mine = np.flatnonzero((src == s) & ~demo)
        arms = int(arm[mine].max()) + 1
        steps = int(step[mine].max()) + 1
        frames = np.zeros(steps * arms, LABEL_DTYPE)
        frames["t"] = np.repeat(np.arange(steps), arms)
        frames["arm"] = np.tile(np.arange(arms), steps)
        frames["observed"] = False  # a step the export left out: nothing seen
        frames["human"] = frames["action"] = -1
        frames["mode"] = _FAULT_CODE
        frames["goal"] = np.nan
        at = step[mine] * arms + arm[mine]
        for name in ("session", "observed", "mode", "human", "action", "success",
                     "violation", "goal"):
            frames[name][at] = columns[name][mine]
        got = classify(frames, arms, DEFAULT_PRE_STEPS)
        out["frame_class"][mine] = got.classes[at]
        out["episode_outcome"][mine] = got.outcomes[at]
        out["class_episode"][mine] = got.episodes[at]
    for s in np.unique(src[demo]):
        mine = np.flatnonzero((src == s) & demo)
        eps = episode_index[mine]
        for chain, e in enumerate(np.unique(eps)):
            rows = mine[eps == e]
            acted = rows[columns["action"][rows] >= 0]
            outcome = demo_outcome(columns["success"][acted], columns["violation"][acted])
            out["frame_class"][rows] = int(FrameClass.DEMO)
            out["episode_outcome"][rows] = int(outcome)
            out["class_episode"][rows] = chain
    return out
