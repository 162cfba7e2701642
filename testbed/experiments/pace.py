"""How long a fleet step and a gradient step take: the rates behind the time estimate
before step 1 (``testbed.experiments.time_plan``), each with where it came from.

Why: a physical trial's pretraining is hours of arm time and gradient steps, and the
estimate is only as good as its rates; the operator must see which are measured and
which assumed. A fleet step, in order of preference:

1. ``measured push``: the rows of earlier runs of these very arms in the folder of runs
   whose hosts report ``readings.push_s`` (the YuMi's motion on its host's clock): per
   step the slowest arm's (a fleet's hosts push at once), the median over steps;
2. ``measured step``: those rows' ``duration_s`` (the whole step: the push, the humans
   and the training step; an upper bound for a collection's step);
3. ``nominal``: what the hosts' backends declare (``Backend.nominal_push_s``, the
   slowest host's); :data:`UNDECLARED_PUSH_S` for a backend that declares none.

How often a push violates (each violation costs its arm t_R steps of hard reset) comes
from the same rows (the humans' teleop pushes, the policy's own), else an assumed rate.

A gradient step is timed here, now: policy updates and critic updates of a learner of
the config's ensemble at its batch size (a couple of seconds each at the paper's sizes on
2 CPU cores, less on a GPU), on random images, after a warm-up, the median of up to
three within a few seconds: what a pretraining step costs on this machine under its
load now (one step alone swung about 2x between runs). Never read from the learner's
own code paths' counters: nothing to keep in step.
"""

from __future__ import annotations

import json
import statistics
import time
import tomllib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np

from testbed.core.backend_registry import DEFAULT_BACKEND, backend_of
from testbed.core.types import IMAGE_SIZE
from testbed.experiments.fleet_config import FleetConfig
from testbed.learning.learning_config import LearningConfig

__all__ = ["ASSUMED_POLICY_VIOLATION", "ASSUMED_TELEOP_VIOLATION", "UNDECLARED_PUSH_S",
           "FleetPace", "GradPace", "fleet_pace", "measure_gradient", "rows_of_runs"]

UNDECLARED_PUSH_S: Final = 10.0
"""A fleet step of a backend that declares no ``nominal_push_s`` (a lab's plugin)."""
ASSUMED_TELEOP_VIOLATION: Final = 0.01
"""Violations per human teleop push, until runs say: a person rarely pushes a cube out."""
ASSUMED_POLICY_VIOLATION: Final = 0.05
"""Violations per push of the noisy pretrained policy, until runs say (the twin's BC
policy violates 0.019 per push without noise, docs/notes/fleet.md; the rollouts take a
random action one push in five)."""
RECENT_RUNS: Final = 8
ROWS_PER_RUN: Final = 500
MIN_STEPS: Final = 5
"""Fewer measured steps than this: not a measure."""
MIN_PUSHES: Final = 20
"""Fewer pushes of a kind than this: its violation rate is assumed."""
GRAD_SAMPLES: Final = 3
"""Gradient steps of each kind timed after the warm-up, at most: their median."""
GRAD_BUDGET_S: Final = 2.0
"""Seconds of timed steps of each kind, at most (one at least): the paper's sizes on 2
cores time one policy step and two or three critic steps, so a ``--dry-run`` stays
within seconds."""
LARGE_SPREAD: Final = 0.25
"""The slowest timed step this much over the fastest: the plan says so."""


@dataclass(frozen=True)
class FleetPace:
    """Seconds a fleet step takes, violation rates, and where each came from."""

    step_s: float
    kind: Literal["measured push", "measured step", "nominal"]
    source: str
    """One line: what was measured or declared, and where."""
    teleop_violation: float = ASSUMED_TELEOP_VIOLATION
    policy_violation: float = ASSUMED_POLICY_VIOLATION
    rates_source: str = "teleop's assumed, policy's assumed"

    @property
    def includes_learning(self) -> bool:
        """A measured trial step already holds its training step and its humans."""
        return self.kind == "measured step"


@dataclass(frozen=True)
class GradPace:
    """Seconds of one policy update and one critic update, and how they were had."""

    policy_s: float
    critic_s: float
    source: str


def _same_arms(config: Path, cfg: FleetConfig) -> bool:
    """Whether the run of ``config`` (its config.toml) drove ``cfg``'s arms on the same
    backends (read as TOML: an old run's fields need not validate today)."""
    try:
        hosts = tomllib.loads(config.read_text(encoding="utf-8")).get("hosts")
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return False
    if not isinstance(hosts, list):
        return False
    try:
        theirs = [(h["name"], h.get("backend", DEFAULT_BACKEND), [a["name"] for a in h["arms"]])
                  for h in hosts]
    except (KeyError, TypeError):
        return False
    return theirs == [(h.name, h.backend, [a.name for a in h.arms]) for h in cfg.hosts]


def rows_of_runs(folders: Iterable[Path], cfg: FleetConfig
                 ) -> dict[Path, list[dict[str, Any]]]:
    """The last ``ROWS_PER_RUN`` rows of each of the ``RECENT_RUNS`` newest runs of
    ``cfg``'s arms found directly in ``folders``, by run."""
    runs: list[Path] = []
    for folder in folders:
        if folder.is_dir():
            runs += [p.parent for p in folder.glob("*/steps.jsonl")
                     if _same_arms(p.parent / "config.toml", cfg)]
    runs = sorted(set(runs), key=lambda r: (r / "steps.jsonl").stat().st_mtime,
                  reverse=True)[:RECENT_RUNS]
    found: dict[Path, list[dict[str, Any]]] = {}
    for run in runs:
        try:
            lines = (run / "steps.jsonl").read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError):
            continue
        rows = found.setdefault(run, [])
        for line in lines[-ROWS_PER_RUN:]:
            try:
                row = json.loads(line)
            except json.JSONDecodeError:  # a torn last line
                continue
            if isinstance(row, dict) and isinstance(row.get("robots"), list):
                rows.append(row)
    return found


def _rate(arms: Sequence[dict[str, Any]], mode: str) -> tuple[float, int] | None:
    pushes = [a for a in arms if a.get("mode") == mode]
    if len(pushes) < MIN_PUSHES:
        return None
    return sum(bool(a.get("violation")) for a in pushes) / len(pushes), len(pushes)


def fleet_pace(cfg: FleetConfig, folders: Sequence[Path]) -> FleetPace:
    """The fleet step of ``cfg``'s arms (see the module's order) from the runs in
    ``folders`` (the folder of runs, a protocol's folder), else nominal."""
    by_run = rows_of_runs(folders, cfg)
    rows = [row for got in by_run.values() for row in got]
    where = ", ".join(sorted({str(r.parent) for r in by_run})) or ", ".join(map(str, folders))
    push = {run: [m for m in map(_slowest_push, got) if m is not None]
            for run, got in by_run.items()}
    took = {run: [float(r["duration_s"]) for r in got
                  if isinstance(r.get("duration_s"), (int, float)) and r["duration_s"] > 0]
            for run, got in by_run.items()}
    arms = [a for row in rows for a in row["robots"] if isinstance(a, dict)]
    teleop, policy = _rate(arms, "teleop"), _rate(arms, "autonomous")
    rates = {"teleop_violation": ASSUMED_TELEOP_VIOLATION if teleop is None else teleop[0],
             "policy_violation": ASSUMED_POLICY_VIOLATION if policy is None else policy[0],
             "rates_source": _rates_source(teleop, policy)}
    for kind, measured, what in (
            ("measured push", push, "the arms' pushes (readings.push_s, the slowest arm's "
             "per step)"),
            ("measured step", took, "whole steps (duration_s, training and humans "
             "included)")):
        values = [v for got in measured.values() for v in got]
        if len(values) >= MIN_STEPS:
            n_runs = sum(1 for got in measured.values() if got)
            return FleetPace(statistics.median(values), kind,  # type: ignore[arg-type]
                             f"{what} over {len(values)} steps of {n_runs} run(s) in {where}",
                             **rates)
    why = (f"only {len(rows)} step(s) of these arms on record in {where}" if rows
           else f"no earlier runs of these arms in {where}")
    return _nominal(cfg, why, rates)


def _slowest_push(row: dict[str, Any]) -> float | None:
    """A step's slowest arm's push (a fleet's hosts push at once), None: none measured."""
    pushes = [float(a["readings"]["push_s"]) for a in row["robots"]
              if isinstance(a, dict) and "push_s" in (a.get("readings") or {})]
    return max(pushes) if pushes else None


def _rates_source(teleop: tuple[float, int] | None, policy: tuple[float, int] | None) -> str:
    said = []
    for what, got in (("teleop", teleop), ("policy", policy)):
        said.append(f"{what}'s assumed" if got is None
                    else f"{what}'s measured over {got[1]} pushes")
    return ", ".join(said)


def _nominal(cfg: FleetConfig, why: str, rates: dict[str, Any]) -> FleetPace:
    declared: dict[str, float] = {}
    undeclared: list[str] = []
    for h in cfg.hosts:
        s = backend_of(h).nominal_push_s
        if s is None:
            undeclared.append(h.backend)
        else:
            declared[h.backend] = max(declared.get(h.backend, 0.0), float(s))
    step = max([*declared.values(), *([UNDECLARED_PUSH_S] if undeclared else [])])
    said = [f"{s:g} s declared by backend {b}" for b, s in sorted(declared.items())]
    said += [f"{UNDECLARED_PUSH_S:g} s assumed for backend {b} (it declares no "
             "nominal_push_s)" for b in sorted(set(undeclared))]
    return FleetPace(step, "nominal", f"nominal: {'; '.join(said)} ({why})", **rates)


def measure_gradient(lc: LearningConfig, critics: Iterable[str] = ("safety", "goal"),
                     clock: Any = time.perf_counter, *, samples: int = GRAD_SAMPLES,
                     budget_s: float = GRAD_BUDGET_S) -> GradPace:
    """Policy updates and critic updates (of ``critics``; none: 0 s) timed on a learner
    of ``lc``'s sizes here, now, on random images: of each, one warm-up step, then up to
    ``samples`` timed while they fit in ``budget_s`` (at least one), their median (one
    step alone swung about 2x between runs with the machine's load); the spread is said
    when it is large. torch's global random state is left as it was (a trial after it
    draws what it would have)."""
    import torch

    from testbed.learning import Learner

    which = tuple(critics)
    with torch.random.fork_rng(devices=[]):
        learner = Learner(lc.model_copy(update={"gradient_steps": 1}), seed=0,
                          train={"policy"})
        rng = np.random.default_rng(0)
        n = 16
        images = rng.integers(0, 256, (n, IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
        actions = rng.integers(0, 4, n)
        learner.add_human(images, actions)
        learner.add_transitions(images, actions, images, np.arange(n) % 4 == 0,
                                np.arange(n) % 4 == 1)
        policy = _timed(learner.train_step, clock, samples, budget_s)
        critic: list[float] = []
        if which:
            learner.set_parts(train=which)
            critic = _timed(learner.train_step, clock, samples, budget_s)
    policy_s = statistics.median(policy)
    critic_s = statistics.median(critic) if critic else 0.0
    counts = f"{len(policy)}" + (f" and {len(critic)}" if critic else "")
    spread = "; ".join(f"{what} {min(t):.3g}-{max(t):.3g} s" for what, t in
                       (("policy", policy), ("critics", critic))
                       if len(t) > 1 and max(t) > (1.0 + LARGE_SPREAD) * min(t))
    return GradPace(policy_s, critic_s,
                    f"the median of {counts} timed here just now after a warm-up "
                    f"(ensemble {lc.ensemble_size}, batch {lc.batch_size}, device "
                    f"{learner.device})" + (f"; spread {spread}: this machine's load"
                                            if spread else ""))


def _timed(step: Callable[[], object], clock: Any, samples: int, budget_s: float
           ) -> list[float]:
    """``step`` once untimed (its first allocations), then timed up to ``samples``
    times: another only while one more, as long as the last, fits in ``budget_s``."""
    step()
    times: list[float] = []
    while len(times) < max(1, samples):
        t0 = clock()
        step()
        times.append(clock() - t0)
        if sum(times) + times[-1] > budget_s:
            break
    return times
