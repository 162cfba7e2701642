"""The humans as people: what each human did in a run, counted from its rows alone.

Why: ROHE weighs "human actions" as if the humans were one pool, and the paper's
simulated experts are all alike; a lab's operators are not. A reviewer (and the lab)
asks who did the interventions, how long each took to act once assigned, how long each
held an arm and how well their pushes did. Everything here comes from ``steps.jsonl``:

* an intervention starts at a row whose arm has the human with ``served == 0`` (rows
  from before ``served`` existed: where the arm's human or kind changes);
* a teleop intervention's first push, and a reset's confirmation, carry ``first``:
  steps from the assignment and the seconds the human's console measured;
* a push is the human's when the arm's mode is ``teleop`` with an action (a push the
  host refused or a cell held is not a push); its success and violation are that
  step's.

Names come from the run's ``config.toml`` (``[[humans.people]]``; without them
``human0``, ``human1``, ...), so the table says "ana", not "human 0".

Beside the counts, each human's estimates at the run's end as the fleet itself made
them online (``testbed.fleet.operators.OperatorModel`` fed the same rows:
:func:`estimate_humans`), and for scripted humans the profile they came from
(:func:`scripted_profiles`), so a reader sees estimate against truth.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from testbed.core.types import HumanEstimate
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.operators import OperatorModel
from testbed.people.people_config import HumanProfile

__all__ = ["HumanCounts", "Profile", "RunHumans", "count_humans", "estimate_humans", "merge",
           "scripted_profiles"]


@dataclass(slots=True)
class HumanCounts:
    """One human's work in one run (or summed over runs: :func:`merge`)."""

    teleops: int = 0
    """Teleop interventions."""
    resets: int = 0
    """Hard-reset interventions."""
    steps_held: int = 0
    """Arm-steps with this human on the arm (teleop, reset, or a push refused)."""
    pushes: int = 0
    successes: int = 0
    """Of ``pushes``: the ones that reached the goal."""
    violations: int = 0
    """Of ``pushes``: the ones that took the cube out of the workspace."""
    first_push_steps: list[int] = field(default_factory=list)
    """Per teleop intervention with a push: steps from the assignment to the first push."""
    first_push_s: list[float] = field(default_factory=list)
    """The same in seconds, where the human's console measured it."""
    reset_steps: list[int] = field(default_factory=list)
    """Per confirmed reset: steps from the assignment to the confirmation, plus one
    (the steps it took)."""

    @property
    def success_rate(self) -> float:
        return self.successes / self.pushes if self.pushes else math.nan


def count_humans(rows: Iterable[Mapping[str, Any]], num_humans: int) -> list[HumanCounts]:
    """Per human index: what they did in the run whose rows these are."""
    out = [HumanCounts() for _ in range(num_humans)]
    last: dict[str, tuple[int, bool]] = {}  # robot -> (human, is reset) of the last row
    for row in rows:
        seen: set[str] = set()
        for r in row["robots"]:
            h = r.get("human")
            robot = r["robot"]
            if h is None or not 0 <= int(h) < num_humans:
                continue
            seen.add(robot)
            c = out[int(h)]
            reset = r["mode"] == "reset"
            served = r.get("served")
            starts = served == 0 if served is not None else last.get(robot) != (h, reset)
            last[robot] = (int(h), reset)
            if starts:
                c.resets += reset
                c.teleops += not reset
            c.steps_held += 1
            _first(c, r, reset)
            if r["mode"] == "teleop" and r.get("action") is not None:
                c.pushes += 1
                c.successes += bool(r["success"])
                c.violations += bool(r["violation"])
        for robot in [k for k in last if k not in seen]:
            del last[robot]  # the arm had no human this step: the next one starts anew
    return out


def _first(c: HumanCounts, r: Mapping[str, Any], reset: bool) -> None:
    first = r.get("first")
    if first is None:
        return
    if reset:
        c.reset_steps.append(int(first["steps"]) + 1)
        return
    c.first_push_steps.append(int(first["steps"]))
    if first.get("s") is not None:
        c.first_push_s.append(float(first["s"]))


def merge(runs: Sequence[HumanCounts]) -> HumanCounts:
    """One human's counts over several runs (an algorithm's trials): sums and pooled lists."""
    m = HumanCounts()
    for c in runs:
        m.teleops += c.teleops
        m.resets += c.resets
        m.steps_held += c.steps_held
        m.pushes += c.pushes
        m.successes += c.successes
        m.violations += c.violations
        m.first_push_steps += c.first_push_steps
        m.first_push_s += c.first_push_s
        m.reset_steps += c.reset_steps
    return m


@dataclass(frozen=True, slots=True)
class Profile:
    """What a scripted human was told to be (``[[humans.people]]``): the truth the
    estimates are read against."""

    skill: float
    """The chance a teleop push is the expert's (not a success rate: the expert's own
    pushes succeed only part of the time)."""
    latency: int
    """Steps before a first action."""
    reset_steps: int
    """Steps a hard reset takes: t_R + latency (``ScriptedHumans``)."""


@dataclass(frozen=True, slots=True)
class RunHumans:
    """One run's humans, by index, for the per-human table."""

    names: list[str]
    counts: list[HumanCounts]
    estimates: list[HumanEstimate] = field(default_factory=list)
    """At the run's end (:func:`estimate_humans`); empty: not estimated."""
    profiles: list[Profile | None] = field(default_factory=list)
    """Scripted humans' profiles (:func:`scripted_profiles`); None for a person."""


def estimate_humans(rows: Iterable[Mapping[str, Any]], num_humans: int,
                    algorithm: Mapping[str, Any]) -> list[HumanEstimate]:
    """Per human index: what the fleet's own model said of them after the run's last
    row (``algorithm``: the run's ``[algorithm]`` table, for t_T and t_R)."""
    defaults = AlgorithmConfig()
    model = OperatorModel(num_humans, int(algorithm.get("t_T", defaults.t_T)),
                          int(algorithm.get("t_R", defaults.t_R)))
    model.observe_all(rows)
    return model.estimates()


def scripted_profiles(humans: Mapping[str, Any], num_humans: int,
                      algorithm: Mapping[str, Any]) -> list[Profile | None]:
    """Per human index: the scripted profile of a run's ``[humans]`` table (its
    ``people``; defaults: the perfect, instant expert), or None for every human when
    the humans were people at a console (``kind`` gui or web)."""
    if humans.get("kind", "scripted") != "scripted":
        return [None] * num_humans
    t_R = int(algorithm.get("t_R", AlgorithmConfig().t_R))
    people = list(humans.get("people") or [])
    out: list[Profile | None] = []
    for h in range(num_humans):
        given = people[h] if h < len(people) else {}
        skill = float(given.get("skill", HumanProfile.model_fields["skill"].default))
        latency = int(given.get("latency", HumanProfile.model_fields["latency"].default))
        out.append(Profile(skill, latency, t_R + latency))
    return out
