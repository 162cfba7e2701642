"""The learner's side of a fleet-loop test that does not learn: a base for fakes.

Why: the loop tests (presence, cell holds, priority signals) drive ``FleetLoop`` with a
fake learner that only acts; the three calls it must also answer, and answer with
nothing, are here once.
"""

from __future__ import annotations

from typing import Any

import numpy as np


class QuietLearner:
    """Takes labels and transitions and trains nothing; a subclass gives ``act``."""

    def add_human(self, images: np.ndarray, actions: np.ndarray,
                  humans: np.ndarray | None = None) -> None:
        return None

    def add_transitions(self, *args: Any) -> None:
        return None

    def train_step(self) -> dict[str, float]:
        return {}
