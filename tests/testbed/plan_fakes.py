"""A world with known rates, run by the real fleet loop, for the planner's tests.

Why: the planner fits what a run's rows say about requests, pushes and people, and then
replays Algorithm 1; to test both against the truth the rows must come from the real
loop (its allocator, its modes, ``served`` and ``first``, the scripted humans' latency,
reset length and availability) in a world whose rates are set by hand. The hosts here
push with fixed chances (the policy's face 2, the expert's face 1: a scripted human of
skill 1), the learner's uncertainty is a fresh uniform draw per arm-step, so an arm asks
for a teleop (C.U.R.'s u >= u_hat) with probability ``1 - u_hat(t)``. A run of a few
hundred steps takes about a second.

With ``trouble`` set, each arm also has the planner's hidden state (as the twin has,
``testbed.planning.plan_trouble``): calm, it asks and pushes as above; in trouble, it
asks with ``trouble.ask`` and its policy pushes with ``trouble.push``; after a step on its
own it falls into trouble or recovers, after a human's push (the expert's face) it is
calm with ``trouble.fixed``, after a violating step troubled with ``trouble.start``.
Hosts and learner share each arm's state (``ArmStates``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import tomli_w
from loop_fakes import QuietLearner

from testbed.core.types import IMAGE_SIZE, ArmObservation, PushResult
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import get_algorithm
from testbed.fleet.loop import FleetLoop
from testbed.people.people_config import HumanProfile
from testbed.records.steps import RunWriter

POLICY_FACE = 2
EXPERT_FACE = 1


@dataclass(frozen=True)
class Trouble:
    """The hidden state's rates (``plan_trouble``'s model, set by hand)."""

    ask: float = 0.9
    push: tuple[float, float] = (0.05, 0.2)
    to_trouble: float = 0.08
    recover: float = 0.05
    fixed: float = 0.9
    start: float = 0.1


@dataclass(frozen=True)
class World:
    """The truth the planner should find."""

    request_early: float = 0.4
    """P(an arm asks for a teleop) for t < ``switch``."""
    request_late: float = 0.15
    switch: int = 100
    policy: tuple[float, float] = (0.2, 0.05)
    """Per autonomous push: P(success), P(violation)."""
    human: tuple[float, float] = (0.5, 0.02)
    """Per teleop push (the expert's face)."""
    t_T: int = 3
    t_R: int = 4
    trouble: Trouble | None = None
    """The arms' hidden state; None: always calm."""

    def request(self, t: int) -> float:
        return self.request_early if t < self.switch else self.request_late


U_HAT = 0.5
"""The threshold; the learner scales its draws so that P(u >= U_HAT) is the world's."""


@dataclass
class ArmStates:
    """Each arm's hidden state (by index) and the generator that moves it."""

    troubled: np.ndarray
    rng: np.random.Generator


class KnownHosts:
    """Arms whose pushes succeed or violate with the world's chances."""

    def __init__(self, arms: Sequence[str], world: World, seed: int,
                 states: ArmStates | None = None) -> None:
        self.robot_names = list(arms)
        self.world = world
        self.states = states
        self.rng = np.random.default_rng(seed)
        self.violating = dict.fromkeys(arms, False)
        self.image = np.zeros((IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8)

    def observe(self) -> dict[str, ArmObservation]:
        return {r: ArmObservation(r, self.image, self.violating[r], (0.5, 0.5), EXPERT_FACE)
                for r in self.robot_names}

    def execute(self, pushes: Mapping[str, int], resets: Sequence[str]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for i, r in enumerate(self.robot_names):
            was_violating = self.violating[r]
            if r in resets:
                self.violating[r] = False
            action = pushes.get(r)
            troubled = self.states is not None and bool(self.states.troubled[i])
            if self.states is not None and self.world.trouble is not None:
                self._move(i, was_violating, action == EXPERT_FACE, self.world.trouble)
            if action is None:
                out[r] = PushResult(r, None, False, False)
                continue
            s, v = (self.world.human if action == EXPERT_FACE
                    else self.world.trouble.push if troubled and self.world.trouble
                    else self.world.policy)
            u = self.rng.random()
            success, violation = u < s, s <= u < s + v
            self.violating[r] = self.violating[r] or violation
            out[r] = PushResult(r, action, bool(success), bool(violation))
        return out


    def _move(self, i: int, was_violating: bool, human_push: bool, tr: Trouble) -> None:
        """The arm's state after this step (plan_trouble's kinds, in its order)."""
        assert self.states is not None
        u = self.states.rng.random()
        if was_violating:
            self.states.troubled[i] = u < tr.start
        elif human_push:
            self.states.troubled[i] = u >= tr.fixed
        elif self.states.troubled[i]:
            self.states.troubled[i] = u >= tr.recover
        else:
            self.states.troubled[i] = u < tr.to_trouble


class KnownLearner(QuietLearner):
    """Pushes face 2; its uncertainty is above ``U_HAT`` with the world's request rate."""

    def __init__(self, world: World, seed: int, states: ArmStates | None = None) -> None:
        self.world = world
        self.rng = np.random.default_rng(seed)
        self.t = 0
        self.states = states

    def act(self, images: np.ndarray) -> Any:
        n = len(images)
        p: Any = self.world.request(self.t)
        if self.states is not None and self.world.trouble is not None:
            p = np.where(self.states.troubled, self.world.trouble.ask, p)
        self.t += 1
        asks = self.rng.random(n) < p
        u = np.where(asks, U_HAT + (1 - U_HAT) * (1 - self.rng.random(n)),
                     U_HAT * self.rng.random(n))
        z = np.zeros(n)
        return SimpleNamespace(actions=np.full(n, POLICY_FACE), uncertainty=u, risk=z,
                               goal_risk=z, novelty=z)


def run_world(folder: Path, world: World, *, arms: int, people: Sequence[HumanProfile],
              steps: int, seed: int, label: str = "cur") -> Path:
    """One run of the real loop in ``world``, written as a finished run folder."""
    names = [f"cell{i // 2}/{'left' if i % 2 == 0 else 'right'}" for i in range(arms)]
    m = len(people)
    params = AlgorithmConfig(t_T=world.t_T, t_R=world.t_R, t_I=0, u_hat=U_HAT, r_hat=1.0)
    algorithm = get_algorithm("cur", params, arms, m, seed=seed,
                              on_site=[p.where == "on_site" for p in people])
    folder.mkdir(parents=True)
    states = None
    if world.trouble is not None:
        rng = np.random.default_rng([seed, 7])
        states = ArmStates(rng.random(arms) < world.trouble.start, rng)
    with RunWriter(folder) as writer:
        loop = FleetLoop(hosts=KnownHosts(names, world, seed, states),
                         learner=KnownLearner(world, seed, states),
                         humans=ScriptedHumans(people, seed=seed, robots=names),
                         algorithm=algorithm, writer=writer, steps=steps, num_humans=m,
                         t_T=world.t_T, t_R=world.t_R, overlap_act=False)
        try:
            for t in range(steps):
                loop.step(t)
        finally:
            loop.close()
    people_rows = [p.model_dump() for p in people]
    (folder / "config.toml").write_text(tomli_w.dumps({
        "humans": {"count": m, "kind": "scripted", "people": people_rows},
        "algorithm": {"name": "cur", "t_T": world.t_T, "t_R": world.t_R, "t_I": 0,
                      "u_hat": U_HAT, "r_hat": 1.0}}))
    (folder / "run.json").write_text(json.dumps({
        "options": {"algorithm": "cur", "label": label, "steps": steps, "seed": seed},
        "status": "complete"}))
    return folder
