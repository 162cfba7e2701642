"""What a trial or a protocol is about to do before step 1, and how long it will take.

Why (issue 44, "No hidden hour"): without ``--policy`` a physical trial first collects
hundreds of teleoperated demonstrations, trains the policy, rolls it out for the
critics' data and trains the critics: over an hour at a real arm's pace on a 2-core
machine, and nothing said so. ``testbed trial``, ``protocol`` (and ``rehearse``, through
``run_protocol``), ``collect`` and ``pretrain`` now print this plan before anything
moves, and ``--dry-run`` prints it alone.

The phases theta_0 still needs (what its cache holds is skipped and said so:
``testbed.experiments.theta0.cache_state``), then the runs:

* collect demonstrations: the pairs still missing; fleet steps = pairs x (1 + v x t_R)
  / arms + 1 (every arm teleoperated at once, a violation takes its arm t_R steps of
  hard reset, a pair is kept on the step after its push);
* pretrain the policy: ``pretrain_steps`` gradient steps;
* roll out the policy: ``critic_transitions`` pushes, as the collection's steps;
* pretrain the critics: ``critic_steps`` gradient steps (none without a critic);
* the runs: their steps left, each a fleet step plus ``gradient_steps`` training steps
  of what its algorithm trains.

The rates and their sources: ``testbed.experiments.pace``. The arithmetic is pure
(:func:`theta0_phases`, :func:`run_seconds`), so it is tested from given rates.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from testbed.experiments.fleet_config import FleetConfig
from testbed.experiments.pace import FleetPace, GradPace, fleet_pace, measure_gradient
from testbed.experiments.pretraining import critic_set
from testbed.experiments.theta0 import CacheState, Theta0Spec, cache_state, theta0_folder
from testbed.fleet.algorithms import ALGORITHMS
from testbed.learning.learning_config import LearningConfig
from testbed.records.run_dir import RunDir

if TYPE_CHECKING:
    from testbed.experiments.trial import TrialOptions

__all__ = ["Phase", "Plan", "Target", "duration", "fleet_steps", "plan_lines",
           "protocol_plan", "run_seconds", "theta0_phases", "trial_plan"]

Measure = Callable[[LearningConfig, Iterable[str]], GradPace]


class ProtocolFile(Protocol):
    """What a plan reads of a protocol (``testbed.experiments.protocol.Protocol``), named
    here rather than imported: ``run_protocol`` prints this plan, so this module must
    not import that one."""

    @property
    def fleet(self) -> FleetConfig: ...
    @property
    def algorithms(self) -> list[str]: ...
    @property
    def trials(self) -> int: ...
    @property
    def steps(self) -> int: ...
    @property
    def humans(self) -> str: ...
    @property
    def evaluate_steps(self) -> int: ...
    @property
    def prompt_when(self) -> str: ...
    @property
    def until(self) -> Any: ...
    def fleet_of(self, name: str) -> FleetConfig: ...
    def algorithm_of(self, name: str) -> str: ...
    def evaluated(self) -> list[str]: ...
    def pretrain_seed(self, k: int) -> int | None: ...


@dataclass(frozen=True)
class Phase:
    """One line of the plan: what, how many, how long; ``skipped`` with why in ``note``."""

    name: str
    count: int
    unit: str
    seconds: float
    fleet_steps: int = 0
    note: str = ""
    skipped: bool = False
    theta0: bool = True
    """A phase of theta_0 (else a run's steps)."""


@dataclass(frozen=True)
class Target:
    """One theta_0 to have before step 1: its fleet, its critics, its cache's state."""

    cfg: FleetConfig
    critics: tuple[str, ...]
    state: CacheState
    label: str = ""
    """Which of several theta_0 it is (a protocol's way), or ""."""


@dataclass
class Plan:
    """The phases in order, the rates they were reckoned with, and what to say."""

    phases: list[Phase]
    fleet: FleetPace
    grad: GradPace | None
    notes: list[str] = field(default_factory=list)

    @property
    def total_s(self) -> float:
        return sum(p.seconds for p in self.phases)

    @property
    def pretrains(self) -> bool:
        """Whether any theta_0 phase is still to do before step 1."""
        return any(p.theta0 and not p.skipped for p in self.phases)


class _Grad:
    """The gradient rates, measured at most once per learner shape, when first needed."""

    def __init__(self, given: GradPace | Measure | None) -> None:
        self._given = given
        self._memo: dict[tuple[int, int, str, tuple[str, ...]], GradPace] = {}
        self.used: GradPace | None = None

    def __call__(self, lc: LearningConfig, critics: Iterable[str]) -> GradPace:
        if isinstance(self._given, GradPace):
            self.used = self._given
            return self._given
        key = (lc.ensemble_size, lc.batch_size, lc.device, tuple(critics))
        if key not in self._memo:
            self._memo[key] = (self._given or measure_gradient)(lc, key[3])
        self.used = self._memo[key]
        return self.used


def fleet_steps(pushes: int, arms: int, violation: float, t_R: int) -> int:
    """Fleet steps to keep ``pushes`` transitions with ``arms`` arms pushing at once:
    each violation takes its arm ``t_R`` steps of hard reset, and a push's pair is kept
    on the step after it."""
    if pushes <= 0:
        return 0
    return math.ceil(pushes * (1.0 + violation * t_R) / max(1, arms)) + 1


def theta0_phases(target: Target, fleet: FleetPace, grad: Callable[[LearningConfig,
                  Iterable[str]], GradPace], demos_planned: dict[Path, int] | None = None
                  ) -> list[Phase]:
    """The four phases of ``target``'s theta_0, what its cache holds skipped.
    ``demos_planned``: demonstrations an earlier target of the same plan collects into
    the same shared file (updated here)."""
    cfg, st, lc = target.cfg, target.state, target.cfg.learning
    tag = f" ({target.label})" if target.label else ""
    if st.done:
        return [Phase(f"theta_0{tag}", 1, "learner", 0.0, note=f"cached: {st.folder}",
                      skipped=True)]
    arms, t_R = len(cfg.robot_names), cfg.algorithm.t_R
    planned = demos_planned if demos_planned is not None else {}
    have = max(st.demos, planned.get(st.demos_file, 0))
    planned[st.demos_file] = max(have, lc.demos)
    out = [collect_phase(cfg, have, lc.demos, fleet, st.demos_file, tag)]
    if st.policy:
        out.append(Phase(f"pretrain the policy{tag}", lc.pretrain_steps, "gradient steps",
                         0.0, note="checkpointed (policy.pt)", skipped=True))
    else:
        out.append(Phase(f"pretrain the policy{tag}", lc.pretrain_steps, "gradient steps",
                         lc.pretrain_steps and lc.pretrain_steps
                         * grad(lc, target.critics).policy_s))
    if not target.critics or lc.critic_transitions == 0:
        why = "no critic to pretrain" if not target.critics else "critic_transitions = 0"
        out.append(Phase(f"roll out the policy{tag}", lc.critic_transitions, "pushes", 0.0,
                         note=why, skipped=True))
    else:
        left = max(0, lc.critic_transitions - st.rollouts)
        steps = fleet_steps(left, arms, fleet.policy_violation, t_R)
        out.append(Phase(f"roll out the policy{tag}", lc.critic_transitions, "pushes",
                         steps * fleet.step_s, steps,
                         _kept(st.rollouts, lc.critic_transitions, st.folder / "rollouts.npz"),
                         skipped=left == 0))
    if not target.critics:
        out.append(Phase(f"pretrain the critics{tag}", 0, "gradient steps", 0.0,
                         note="no critic to pretrain", skipped=True))
    else:
        out.append(Phase(f"pretrain the critics{tag}", lc.critic_steps, "gradient steps",
                         lc.critic_steps and lc.critic_steps
                         * grad(lc, target.critics).critic_s,
                         note=", ".join(target.critics)))
    return out


def collect_phase(cfg: FleetConfig, have: int, count: int, fleet: FleetPace, where: Path,
                  tag: str = "") -> Phase:
    """Collecting ``count`` demonstrations of ``cfg``'s arms, ``have`` kept in ``where``."""
    left = max(0, count - have)
    steps = fleet_steps(left, len(cfg.robot_names), fleet.teleop_violation,
                        cfg.algorithm.t_R)
    return Phase(f"collect demonstrations{tag}", count, "pairs", steps * fleet.step_s, steps,
                 _kept(have, count, where), skipped=left == 0)


def _kept(have: int, want: int, where: Path) -> str:
    if have >= want:
        return f"cached: {where}"
    return f"{have} kept in {where}, {want - have} to go" if have else ""


def run_seconds(cfg: FleetConfig, algorithm: str, steps: int, fleet: FleetPace,
                grad: Callable[[LearningConfig, Iterable[str]], GradPace] | None,
                critics: Iterable[str] = ()) -> float:
    """``steps`` steps of ``algorithm`` on ``cfg``: a fleet step each, plus its training
    (``gradient_steps`` updates of what it trains; none for BC, an evaluation (``grad``
    None) or a measured whole step, which holds its training already)."""
    per_step = fleet.step_s
    spec = ALGORITHMS[algorithm]
    if grad is not None and not fleet.includes_learning and spec.learns and steps:
        g = grad(cfg.learning, tuple(critics))
        per_step += cfg.learning.gradient_steps * (
            g.policy_s + (g.critic_s if spec.critics else 0.0))
    return steps * per_step


def trial_plan(cfg: FleetConfig, opts: TrialOptions, start: int = 0, *,
               grad: GradPace | Measure | None = None) -> Plan:
    """A trial's plan: theta_0's phases (none when resumed at ``start`` > 0, given
    ``--policy`` or the expert's row), then its steps from ``start``. ``grad``: the
    gradient rates (default: measured here)."""
    out = Path(opts.out)
    fleet = fleet_pace(cfg, [out])
    rates = _Grad(grad)
    phases: list[Phase] = []
    notes: list[str] = []
    if start > 0:
        notes.append(f"theta_0: not needed, the run resumes at step {start}")
    elif opts.policy is not None or opts.expert:
        notes.append("theta_0: not needed, " + (f"--policy {opts.policy}" if opts.policy
                                                  else "the expert drives every arm"))
    else:
        which = critic_set(ALGORITHMS[opts.algorithm].critics | set(opts.pretrain_critics
                                                                     or ()))
        phases += theta0_phases(Target(cfg, which, cache_state(out, cfg, which)), fleet,
                                rates)
    steps = opts.steps - start
    critics = ALGORITHMS[opts.algorithm].critics
    phases.append(Phase(f"trial {opts.name or opts.algorithm}", steps, "steps",
                        run_seconds(cfg, opts.algorithm, steps, fleet,
                                    None if opts.evaluate else rates, critics), steps,
                        theta0=False))
    return Plan(phases, fleet, rates.used, notes)


def theta0_plan(targets: Sequence[Theta0Spec], folder: Path, *,
                grad: GradPace | Measure | None = None) -> Plan:
    """The phases of each theta_0 of ``targets`` (its fleet, critics, label and seed)
    under the folder of runs ``folder``: ``testbed pretrain``'s plan."""
    fleet = fleet_pace(targets[0].cfg, [folder])
    rates = _Grad(grad)
    phases = _targets_phases(targets, folder, fleet, rates)
    return Plan(phases, fleet, rates.used)


def file_plan(cfg: FleetConfig, demos: Path, count: int, *,
              grad: GradPace | Measure | None = None) -> Plan:
    """``testbed pretrain --demos NPZ``'s plan: ``count`` demonstrations given, then a
    theta_0 of both critics (nothing cached: it goes to a file)."""
    from testbed.experiments.pretraining import CRITICS

    fleet = fleet_pace(cfg, [Path(cfg.trial.out)])
    rates = _Grad(grad)
    fresh = CacheState(demos.parent, demos, False, count, False, 0)
    given = cfg.model_copy(update={"learning": cfg.learning.model_copy(
        update={"demos": count})})
    collect, *rest = theta0_phases(Target(given, CRITICS, fresh), fleet, rates)
    return Plan([replace(collect, note=f"given: {demos}"), *rest], fleet, rates.used)


def collect_plan(cfg: FleetConfig, count: int, have: int, where: Path, folder: Path
                 ) -> Plan:
    """``testbed collect``'s plan: ``count`` pairs into ``where``, ``have`` kept."""
    fleet = fleet_pace(cfg, [folder])
    return Plan([collect_phase(cfg, have, count, fleet, where)], fleet, None)


def protocol_targets(proto: ProtocolFile, runs: Iterable[tuple[str, int]] | None = None
                     ) -> list[Theta0Spec]:
    """Each theta_0 the runs ``runs`` (algorithm, trial; default: all) start from: its
    fleet, its critics (any algorithm of the protocol reads: ``run_protocol_run``), its
    seed (the trial's with ``pretrain_per_trial``) and, when there are several, which:
    the algorithms it is for (a way's fleet may shape theta_0), its trial, or both."""
    union = proto.theta0_critics()
    todo = [(a, k) for a in proto.algorithms for k in range(proto.trials)] \
        if runs is None else list(runs)
    per_trial = any(proto.pretrain_seed(k) is not None for _, k in todo)
    found: dict[tuple[Path, int | None], tuple[FleetConfig, tuple[str, ...], list[str]]] = {}
    for a, k in sorted(todo, key=lambda run: run[1] if per_trial else 0):
        cfg = proto.fleet_of(a)
        critics = critic_set(set(ALGORITHMS[proto.algorithm_of(a)].critics) | set(union))
        key = (theta0_folder(Path(), cfg, critics), k if per_trial else None)
        found.setdefault(key, (cfg, critics, []))[2].append(a)
    several = len({folder for folder, _ in found}) > 1
    out = []
    for (_, k), (cfg, critics, who) in found.items():
        label = ", ".join(([f"for {', '.join(dict.fromkeys(who))}"] if several else [])
                          + ([] if k is None else [f"trial {k}"]))
        seed = None if k is None else proto.pretrain_seed(k)
        out.append(Theta0Spec(cfg, critics, label) if seed is None
                   else Theta0Spec(cfg, critics, label, seed))
    return out


def protocol_plan(proto: ProtocolFile, folder: Path, *,
                  grad: GradPace | Measure | None = None) -> Plan:
    """A protocol's plan: each theta_0 its runs still to start need, then its training
    runs and its evaluations still to do (``trials`` of them; with ``until``, at least
    those)."""
    fleet = fleet_pace(proto.fleet, [folder])
    rates = _Grad(grad)
    train_s, train_steps, runs_left = 0.0, 0, 0
    starting: list[tuple[str, int]] = []
    for a in proto.algorithms:
        cfg, algorithm = proto.fleet_of(a), proto.algorithm_of(a)
        runs = [RunDir(folder / f"{a}-t{k}") for k in range(proto.trials)]
        for run in runs:
            left = _steps_left(run, proto.steps)
            runs_left += left > 0
            train_steps += left
            train_s += run_seconds(cfg, algorithm, left, fleet, rates,
                                   ALGORITHMS[algorithm].critics)
        starting += [(a, k) for k, r in enumerate(runs)
                     if not r.summary.exists() and not r.state.exists()]
    phases = (_targets_phases(protocol_targets(proto, starting), folder, fleet, rates)
              if starting else [])
    phases.append(Phase("training runs", train_steps, "steps", train_s, train_steps,
                        f"{runs_left} of {proto.trials * len(proto.algorithms)} runs to go",
                        theta0=False))
    evals = _evaluations(proto, folder)
    if evals:
        phases.append(Phase("evaluation runs", sum(evals), "steps",
                            sum(evals) * fleet.step_s, sum(evals), f"{len(evals)} runs",
                            theta0=False))
    return Plan(phases, fleet, rates.used, _protocol_notes(proto))


def _targets_phases(targets: Sequence[Theta0Spec], folder: Path, fleet: FleetPace,
                    rates: _Grad) -> list[Phase]:
    """The phases of every theta_0 of ``targets`` in ``folder``, one collection per set
    of arms and seed however many of them draw on it."""
    planned: dict[Path, int] = {}
    phases: list[Phase] = []
    for cfg, critics, label, seed in targets:
        which = critic_set(critics)
        phases += theta0_phases(Target(cfg, which, cache_state(folder, cfg, which, seed),
                                       label), fleet, rates, planned)
    return phases


def _steps_left(run: RunDir, steps: int) -> int:
    """Steps a protocol run has left: 0 when finished, past its checkpoint when resumed."""
    return 0 if run.summary.exists() else max(0, steps - resumed_start(run.path))


def _evaluations(proto: ProtocolFile, folder: Path) -> list[int]:
    """The steps of each evaluation run not done yet (the paper's, after the runs)."""
    return [proto.evaluate_steps for k in range(proto.trials) for a in proto.evaluated()
            if not (folder / f"eval-{a}-t{k}" / "summary.json").exists()]


def _protocol_notes(proto: ProtocolFile) -> list[str]:
    notes = []
    if proto.until is not None:
        notes.append(f"until: at least {proto.trials} trials (counted here), up to "
                     f"{proto.until.max_trials} if the answer is not settled")
    if proto.prompt_when != "never":
        notes.append("not counted: the operator putting the cubes back at each prompt")
    return notes


def duration(seconds: float) -> str:
    """``42 s``, ``3 min 05 s``, ``2 h 07 min`` (to the nearest minute past an hour)."""
    s = round(seconds)
    if s < 3600:
        return f"{s} s" if s < 60 else f"{s // 60} min {s % 60:02d} s"
    h, m = divmod(round(seconds / 60), 60)
    return f"{h} h {m:02d} min"


def plan_lines(plan: Plan, humans: str, ahead: str | None = "--config FILE", *,
               policy: bool = True) -> list[str]:
    """The plan as the operator reads it: a line per phase (count, fleet steps, time or
    why it is skipped), the total, each rate's source, and how to skip theta_0 or run
    it ahead (``ahead``: the arguments that name this fleet and folder; None: no such
    line, for ``testbed collect``/``pretrain`` themselves; ``policy``: a trial, which
    ``--policy`` starts from a given learner instead)."""
    rows = [("phase", "count", "fleet steps", "time")]
    for p in plan.phases:
        count = f"{p.count} {p.unit}" if p.count or not p.skipped else "-"
        steps = str(p.fleet_steps) if p.fleet_steps else "-"
        when = ("skipped" if p.skipped else f"~{duration(p.seconds)}")
        rows.append((p.name, count, steps, when + (f"  ({p.note})" if p.note else "")))
    rows.append(("total", "", "", f"~{duration(plan.total_s)}"))
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    out = ["Before step 1 (an estimate; testbed/experiments/time_plan.py):"]
    out += ["  " + "  ".join(c.ljust(w) for c, w in zip(r[:3], widths, strict=True)) + "  "
            + r[3] for r in rows]
    f = plan.fleet
    out.append(f"  fleet step {f.step_s:.3g} s: {f.source}")
    out.append(f"  hard resets: {100 * f.teleop_violation:.3g}% of teleop pushes, "
               f"{100 * f.policy_violation:.3g}% of policy pushes violate ({f.rates_source})")
    if plan.grad is not None:
        g = plan.grad
        out.append(f"  gradient step: policy {g.policy_s:.3g} s, critics {g.critic_s:.3g} s: "
                   f"{g.source}")
    if humans != "scripted" and not f.includes_learning:
        out.append("  not counted: the humans' time to choose each teleop push")
    out += [f"  {n}" for n in plan.notes]
    if plan.pretrains and ahead is not None:
        skip = "skip it with --policy learner.pt, or " if policy else ""
        out.append(f"  theta_0: {skip}make it ahead (the same cache; a re-run goes on from "
                   f"what it kept): testbed collect {ahead}, then testbed pretrain {ahead}")
    return out


def print_plan(lines: Sequence[str]) -> None:
    """The plan on stdout, at once (before anything moves)."""
    print("\n".join(lines), flush=True)


def say_protocol_plan(proto: ProtocolFile, folder: Path, ahead: str | None = None) -> Plan:
    """Print ``proto``'s plan for ``folder`` (``run_protocol`` does, before its first
    prompt); ``ahead``: the arguments of ``testbed collect``/``pretrain`` that name it."""
    plan = protocol_plan(proto, folder)
    print_plan(plan_lines(plan, proto.humans,
                          ahead or f"--config PROTOCOL_FILE --runs {folder}", policy=False))
    return plan


def resumed_start(run: Path) -> int:
    """The step a run resumes at (its checkpoint's step + 1; 0 without one)."""
    state = RunDir(run).state
    if not state.exists():
        return 0
    try:
        return int(json.loads(state.read_text())["t"]) + 1
    except (OSError, ValueError, KeyError, TypeError):
        return 0
