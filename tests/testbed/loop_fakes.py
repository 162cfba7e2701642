"""Fakes for fleet-loop tests: a learner that does not learn, hosts whose arms stay put, a
priority function that remembers what it was shown.

Why: the loop tests (presence, cell holds, priority signals) drive ``FleetLoop`` with a
fake learner that only acts (the three calls it must also answer, and answer with
nothing, are here once) and, some of them, with arms that never leave their workspace.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from testbed.core.types import IMAGE_SIZE, ArmObservation, PushResult
from testbed.fleet.priorities import PrioritySignals


class QuietLearner:
    """Takes labels and transitions and trains nothing; a subclass gives ``act``."""

    def add_human(self, images: np.ndarray, actions: np.ndarray,
                  labellers: np.ndarray | None = None) -> None:
        return None

    def add_transitions(self, *args: Any) -> None:
        return None

    def train_step(self) -> dict[str, float]:
        return {}


class CalmHosts:
    """Arms that never leave their workspace; the expert's face is always 1."""

    def __init__(self, arms: Sequence[str]) -> None:
        self.robot_names = list(arms)

    def observe(self) -> dict[str, ArmObservation]:
        img = np.zeros((IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8)
        return {r: ArmObservation(r, img, False, (0.5, 0.5), 1) for r in self.robot_names}

    def execute(self, pushes: Mapping[str, int], resets: Sequence[str]) -> dict[str, Any]:
        return {r: PushResult(r, pushes.get(r), False, False) for r in self.robot_names}


class RecordingPriority:
    """A priority function that keeps the signals it was given, then answers as ``inner``."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.seen: list[PrioritySignals] = []

    def keys(self, signals: PrioritySignals) -> Any:
        self.seen.append(signals)
        return self.inner.keys(signals)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)
