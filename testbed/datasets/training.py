"""A dataset's frames back as what a learner is given: human labels and transitions.

Why apart: this is the one place that says which exported frames the learner learns
from, whatever format they were read from. The human labels are the frames with
``intervention`` != 0 and an action (teleop pushes and the offline demonstrations); the
critics' transitions are every push whose arm's next frame (same source, arm and
session, step + 1) was observed -- what ``testbed.records.store.replay`` gives a resumed
learner, across episode boundaries too (a success's transition ends one episode and its
next image starts the next). ``testbed train`` feeds them to a learner.

Each label keeps its labeller *by name*: a frame's ``human`` is an index into its own
run's people, so indices of two runs are not comparable; the name (``Frames.person``)
is, and merged datasets share one labeller table.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

from testbed.core.types import Mode
from testbed.datasets.episodes import MODE_CODE, POLICY, Frames
from testbed.datasets.sources import DEMO_FIELDS

NO_LABELLER: Final = -1
"""The labeller code of a label no person of a fleet gave (an offline demonstration);
``testbed.learning.data.NO_LABELLER`` (not imported: it pulls in torch)."""


@dataclass
class TrainingData:
    """What ``testbed train`` gives the learner: human labels and critic transitions."""

    images: np.ndarray
    actions: np.ndarray
    labellers: np.ndarray
    """Who gave each label: an index into ``labeller_names`` (``NO_LABELLER``: an offline
    demonstration)."""
    labeller_names: list[str]
    """Labeller code -> the person (``Frames.person``: a name, or an unnamed human's
    source and index); one code per person, however many runs they labelled in."""
    transitions: dict[str, np.ndarray]
    """``testbed.experiments.pretraining.FIELDS`` -> arrays."""

    @staticmethod
    def merge(parts: Sequence[TrainingData]) -> TrainingData:
        """``parts`` in one, each labeller once by name: a person who labelled in two
        parts (under any index) is one labeller; two people never share one."""
        names: dict[str, int] = {}
        codes = []
        for p in parts:
            table = np.array([names.setdefault(n, len(names)) for n in p.labeller_names]
                             + [NO_LABELLER], np.int64)  # [-1] reads NO_LABELLER's
            codes.append(table[p.labellers])
        return TrainingData(
            np.concatenate([p.images for p in parts]),
            np.concatenate([p.actions for p in parts]),
            np.concatenate(codes) if codes else np.zeros(0, np.int64), list(names),
            {k: np.concatenate([p.transitions[k] for p in parts]) for k in DEMO_FIELDS})


def training_data(frames: Frames) -> TrainingData:
    """Human labels (``intervention`` != 0 with an action: teleop pushes and the
    demonstrations), each with its labeller by name (``Frames.person`` of the frame's
    source and ``human``), and transitions (a push, then its arm's next frame observed)."""
    c = frames.columns
    acted = c["action"] >= 0
    label = acted & (c["intervention"] != POLICY)
    pushed = acted & np.isin(c["mode"], (MODE_CODE[Mode.AUTONOMOUS], MODE_CODE[Mode.TELEOP]))
    same = np.ones(max(len(frames) - 1, 0), bool)
    for k in ("source_index", "arm", "session"):
        same &= c[k][1:] == c[k][:-1]
    pair = np.flatnonzero(pushed[:-1] & same & (c["step"][1:] == c["step"][:-1] + 1)
                          & c["observed"][1:])
    names: dict[str, int] = {}
    who = [NO_LABELLER if h < 0 else names.setdefault(frames.person(int(s), int(h)), len(names))
           for s, h in zip(c["source_index"][label].tolist(), c["human"][label].tolist(),
                           strict=True)]
    return TrainingData(
        frames.images[label], c["action"][label], np.asarray(who, np.int64).reshape(-1),
        list(names),
        {"images": frames.images[pair], "actions": c["action"][pair],
         "next_images": frames.images[pair + 1], "violation": c["violation"][pair],
         "success": c["success"][pair]})
