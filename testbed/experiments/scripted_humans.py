"""The twin's scripted humans: operators who differ, by profile, for twin mode.

Why in ``experiments``: they are how a twin trial, protocol or sweep rehearses its
operators (the paper's simulated experts); the fleet loop sees them only through the
``testbed.core.humans.Humans`` contract. Each human follows its
``testbed.people.people_config.HumanProfile``: ``skill`` (how often its push is the expert's),
``latency`` (timesteps before its first action) and ``availability`` (the chance it can
take new work at a step). The default profile is the paper's perfect expert, and its
records are those of the humans before profiles existed.

Every random draw comes from a generator seeded by (trial seed, step, human, arm), not
from a running stream: the same trial gives the same draws, and a resumed trial gives
the draws the uninterrupted one would have, whatever happened before the crash.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from testbed.core.humans import Presence, reset_taker, unnamed_human
from testbed.core.types import (
    NUM_ACTIONS,
    FleetStatus,
    HumanRequest,
    HumanResponse,
    InterventionKind,
)
from testbed.people.people_config import HumanProfile

__all__ = ["ScriptedHumans"]

_SKILL, _AVAILABLE = 1, 2
"""Which draw a generator is for (its seed's last word): independent streams."""


class ScriptedHumans:
    """Teleop from the host's expert action, and hard resets of ``t_R`` steps, by profile.

    Teleop pushes the host's expert action (``ArmObservation.expert_action``, which only
    a twin host reports) with probability ``skill``, else one of the other faces; its
    first push comes on the intervention's ``latency``-th step (``served == latency``;
    the steps before pass without a push). A hard reset is done at the end of the
    ``t_R + latency``-th step it was served (docs/ARCHITECTURE.md, "The timestep").
    Their time to a first action is in steps (the row's ``first.steps``: the profile's
    ``latency``); they report no ``waited_s``: seconds would be the twin's speed, not
    the human's, and would make two runs of one seed differ (the records of a seed are
    the same, serial or overlapped, local or on a Ray worker). A remote profile
    (``where``) is never given a reset in a trial (the allocator's rule, which the
    twin's records show); a reset addressed to one anyway (the data collection before
    a trial, ``testbed.experiments.pretraining``, addresses them by arm index) is done
    as an on-site profile does it (``testbed.core.humans.reset_taker``).
    """

    def __init__(self, profiles: Sequence[HumanProfile] = (), seed: int = 0,
                 robots: Sequence[str] = ()) -> None:
        self.profiles = list(profiles)
        self.seed = int(seed) & 0xFFFFFFFF
        self._robot_index = {r: i for i, r in enumerate(robots)}

    def _profile(self, human: int) -> HumanProfile:
        if human < len(self.profiles):
            return self.profiles[human]
        return HumanProfile(name=unnamed_human(human))

    def _rng(self, t: int, human: int, robot: str, what: int) -> np.random.Generator:
        arm = self._robot_index.get(robot, sum(robot.encode()))
        return np.random.default_rng([self.seed, int(t), human, arm, what])

    def act(self, requests: Sequence[HumanRequest], t: int) -> dict[str, HumanResponse]:
        out: dict[str, HumanResponse] = {}
        for req in requests:
            prof = self._profile(req.human)
            if req.kind is InterventionKind.TELEOP:
                if req.served < prof.latency:
                    out[req.robot] = HumanResponse(req.robot)  # not yet: the step passes
                    continue
                out[req.robot] = HumanResponse(req.robot, action=self._push(req, prof, t))
            else:  # by an on-site profile: a remote person never resets
                places = [p.where for p in self.profiles]
                prof = self._profile(reset_taker(req.human, places))
                done = req.served + 1 >= req.min_steps + prof.latency
                out[req.robot] = HumanResponse(req.robot, reset_done=done)
        return out

    def _push(self, req: HumanRequest, prof: HumanProfile, t: int) -> int:
        expert = req.observation.expert_action
        if expert is None:
            raise RuntimeError(
                f"{req.robot}: scripted humans need a twin host (no expert action); "
                "use --humans gui with physical arms"
            )
        if prof.skill >= 1.0:
            return int(expert)
        rng = self._rng(t, req.human, req.robot, _SKILL)
        if rng.random() < prof.skill:
            return int(expert)
        others = [a for a in range(NUM_ACTIONS) if a != int(expert)]
        return int(others[int(rng.integers(len(others)))])

    def presence_at(self, t: int) -> Presence | None:
        """Who can take new work at step ``t`` (``testbed.core.humans.presence_of``): None
        (everyone, always) unless a profile's ``availability`` is below 1; then each such
        human is there with that chance, drawn for (seed, t, human)."""
        if all(p.availability >= 1.0 for p in self.profiles):
            return None
        available = np.array([
            p.availability >= 1.0
            or bool(self._rng(t, h, "", _AVAILABLE).random() < p.availability)
            for h, p in enumerate(self.profiles)], dtype=bool)
        return Presence(available=available)

    def show(self, t: int, status: FleetStatus) -> None:
        return None

    def close(self) -> None:
        return None
