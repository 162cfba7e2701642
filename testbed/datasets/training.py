"""A dataset's frames back as what a learner is given: human labels and transitions.

Why apart: this is the one place that says which exported frames the learner learns
from, whatever format they were read from. The human labels are the frames with
``intervention`` != 0 and an action (teleop pushes and the offline demonstrations); the
critics' transitions are every push whose arm's next frame (same source, arm and
session, step + 1) was observed -- what ``testbed.records.store.replay`` gives a resumed
learner, across episode boundaries too (a success's transition ends one episode and its
next image starts the next). ``testbed train`` feeds them to a learner.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from testbed.core.types import Mode
from testbed.datasets.episodes import MODE_CODE, POLICY, Frames
from testbed.datasets.sources import DEMO_FIELDS


@dataclass
class TrainingData:
    """What ``testbed train`` gives the learner: human labels and critic transitions."""

    images: np.ndarray
    actions: np.ndarray
    humans: np.ndarray
    """Who gave each label (the run's human index; -1 an offline demonstration)."""
    transitions: dict[str, np.ndarray]
    """``testbed.experiments.pretraining.FIELDS`` -> arrays."""

    @staticmethod
    def merge(parts: Sequence[TrainingData]) -> TrainingData:
        return TrainingData(
            np.concatenate([p.images for p in parts]),
            np.concatenate([p.actions for p in parts]),
            np.concatenate([p.humans for p in parts]),
            {k: np.concatenate([p.transitions[k] for p in parts]) for k in DEMO_FIELDS})


def training_data(frames: Frames) -> TrainingData:
    """Human labels (``intervention`` != 0 with an action: teleop pushes and the
    demonstrations) and transitions (a push, then its arm's next frame observed)."""
    c = frames.columns
    acted = c["action"] >= 0
    label = acted & (c["intervention"] != POLICY)
    pushed = acted & np.isin(c["mode"], (MODE_CODE[Mode.AUTONOMOUS], MODE_CODE[Mode.TELEOP]))
    same = np.ones(max(len(frames) - 1, 0), bool)
    for k in ("source_index", "arm", "session"):
        same &= c[k][1:] == c[k][:-1]
    pair = np.flatnonzero(pushed[:-1] & same & (c["step"][1:] == c["step"][:-1] + 1)
                          & c["observed"][1:])
    return TrainingData(
        frames.images[label], c["action"][label], c["human"][label].astype(np.int64),
        {"images": frames.images[pair], "actions": c["action"][pair],
         "next_images": frames.images[pair + 1], "violation": c["violation"][pair],
         "success": c["success"][pair]})
