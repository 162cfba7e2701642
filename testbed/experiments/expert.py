"""The expert row of the paper's evaluation (8.3.4, Table 2): every arm driven by the
twin's scripted expert, humans for hard resets only.

Why here and so small: the fleet loop acts from images alone, and only a twin host knows
the best push (``ArmObservation.expert_action``). ``ExpertHosts`` passes the hosts
through and keeps the expert's answers of the last observation; ``ExpertPolicy`` is the
learner the loop acts with: its actions are those answers, its signals zero (it has no
uncertainty and no critic), it learns nothing and has no state to checkpoint. The run is
otherwise an evaluation like any other (allocation as BC: C-prioritised resets).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from testbed.core.atomic import atomic_write_json
from testbed.core.hosts import Hosts
from testbed.core.types import NUM_ACTIONS, ArmObservation, Fault
from testbed.core.wrappers import HostsWrapper


class ExpertHosts(HostsWrapper):
    """The hosts, passed through; remembers each arm's expert push at each observe."""

    def __init__(self, hosts: Hosts) -> None:
        super().__init__(hosts)
        self.expert: dict[str, int] = {}

    def observe(self) -> Mapping[str, ArmObservation | Fault]:
        observations = self.hosts.observe()
        self.expert = {r: int(o.expert_action) for r, o in observations.items()
                       if isinstance(o, ArmObservation) and o.expert_action is not None}
        return observations


class ExpertPolicy:
    """The loop's learner for the expert row: the expert's pushes, zero signals."""

    def __init__(self, hosts: ExpertHosts) -> None:
        self._hosts = hosts

    def act(self, images: np.ndarray) -> Any:
        from testbed.learning.api import PolicyOutput

        n = len(self._hosts.robot_names)
        if images.shape[0] != n:
            raise ValueError(f"the expert acts for the fleet's {n} arms, got {images.shape[0]}")
        actions = np.array([self._hosts.expert.get(r, 0) for r in self._hosts.robot_names],
                           dtype=np.int64)
        probs = np.zeros((n, NUM_ACTIONS), dtype=np.float32)
        probs[np.arange(n), actions] = 1.0
        zeros = np.zeros(n, dtype=np.float32)
        return PolicyOutput(actions, probs, zeros, zeros.copy(), zeros.copy(), zeros.copy())

    def add_human(self, images: np.ndarray, actions: np.ndarray,
                  labellers: np.ndarray | None = None) -> None:
        """Never called (the expert row's allocation does not learn)."""

    def add_transitions(self, *args: Any) -> None:
        """Never called (as add_human)."""

    def train_step(self) -> dict[str, float]:
        return {}

    def set_parts(self, **_: Any) -> None:
        """Nothing to train or read."""

    def reseed(self, seed: int) -> None:
        """Nothing random."""

    def state_dict(self) -> dict[str, Any]:
        return {"expert": True}

    def save(self, path: str | Path) -> Path:
        """The run's learner.pt: a marker (there is no policy to keep)."""
        target = Path(path).with_suffix(".json")
        atomic_write_json(target, {"expert": True})
        return target
