"""``testbed plan``'s fit: what a fleet's humans faced, per algorithm, from the step rows.

Why from the rows: a lab asks "how many people for how many arms" before it can afford a
sweep on the robots, and every finished run already holds the answer's ingredients
(docs/notes/plan.md). Each ``steps.jsonl`` row records, per arm, its key (so whether the
arm asked for a human, whatever it got), its mode (so whether it was violating: ``idle``
or ``reset``), who pushed and what came of it, and on an intervention's first action
``first.steps`` (a teleop's latency, a reset's length). This module counts those, per
algorithm (the run's label: run.json ``options.label``, else its algorithm), into the
processes :mod:`testbed.planning.plan_sim` replays at other fleet sizes:

=====================  ==========================================================
process                counted from the rows (by phase: bins of ``bin_steps`` steps)
=====================  ==========================================================
teleop requests        an arm not violating and not held (a teleop under t_T, a
                       reset under t_R) whose key is > 0; apart: right after a
                       teleop of its own (``continues``: how long teleops run past
                       t_T), else (``requests``)
reset eligibility      a violating arm's key > 0 (only for keys without ``c``,
                       e.g. the ``u`` ablation; with ``c`` it is the rule: always,
                       or from t_I for C.U.R.)
policy pushes          per autonomous push: success, violation, neither
each human's pushes    per teleop push: success, violation, neither
latency                per teleop: ``first.steps`` of its first push
reset length           per confirmed reset: ``first.steps + 1``
availability           per step: the human is in the row's ``away`` or not
=====================  ==========================================================

The posteriors (:meth:`PlanFit.draw`) are what the intervals come from: per replicate,
every rate is redrawn from its Beta or Dirichlet posterior, each human's latency and
reset lengths by a Bayesian bootstrap of the ones observed. The priors borrow
``testbed.fleet.operators``'s reasoning (a human's push rates shrink towards the
humans' pool with ``PRIOR_PUSHES`` pseudo-pushes, the pool towards the policy with
``POOL_PUSHES``; times towards the pool with ``PRIOR_TIMES``) so a human with few pushes
reads as the fleet's average; a phase bin's rate shrinks towards the run's whole rate
with ``PRIOR_BIN`` pseudo arm-steps, so a sparse bin is not a coin of its own.

Those counts describe the runs (the plan's tables, the tests); what the simulation
replays of the arms is the trouble model fitted on the same rows
(:mod:`testbed.planning.plan_trouble`: each arm calm or in trouble, its requests and
its policy's pushes by that hidden state), and of the humans the rows above.

Over 450 lines, on purpose: the fit of one run's rows: the processes (rates, outcomes,
the humans, the draws) share the same bins and counts, and ``PlanFit`` is read whole by
the simulation.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np
import numpy.typing as npt

from testbed.core.config import ConfigError
from testbed.core.humans import unnamed_human
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import ALGORITHMS, get_algorithm
from testbed.fleet.operators import POOL_PUSHES, PRIOR_PUSHES, PRIOR_TIMES
from testbed.planning.plan_trouble import (
    ArmSequences,
    TroubleCounts,
    TroubleDraws,
    arm_sequences,
    draw_trouble,
    fit_trouble,
)
from testbed.records.metrics import summarize
from testbed.records.run_dir import EVAL_PREFIX, display_names
from testbed.records.steps import read_steps

__all__ = ["BIN_STEPS", "METRICS", "Draws", "HumanFit", "KeyOrder", "PlanFit", "Processes",
           "Rates", "fit_runs", "key_order", "run_metrics"]

BIN_STEPS: Final = 25
"""Steps per phase bin: at 4 arms and 2 trials, 200 arm-steps per bin, so a request rate
near 0.3 has a standard error near 0.03, while a 150-step run still has 6 phases to show
the policy learning."""
PRIOR_BIN: Final = 2.0
"""Pseudo arm-steps (or pushes) of a bin's prior, at the run's whole rate."""
METRICS: Final = ("successes", "hard_resets", "idle_time", "human_actions", "rohe",
                  "utilisation", "wait", "unserved")
"""What the plan predicts per point; the first five are ``testbed.records.metrics``'s.
utilisation: human-steps on an arm / (M x T); wait: idle arm-steps (violating, no one
there yet) per hard reset; unserved: the share of teleop requests no one took."""

KeyOrder = Literal["resets_first", "teleops_first", "mixed"]
"""Where a violating arm's key sorts against a teleop request's: the algorithm's key has
``c`` before its request signals (C.U.R., Random, BC), after them (Fleet-ED, Fleet-TD),
or no ``c`` at all (the ``u``, ``r``, ``ur``, ``ru`` ablations: one order for both)."""

_IDLE: Final = frozenset({"idle", "reset"})
_SKIP: Final = frozenset({"fault", "refused"})


def key_order(algorithm: str) -> KeyOrder:
    """The algorithm's key structure, from the registry's own priority function."""
    if algorithm not in ALGORITHMS:
        return "resets_first"
    names = get_algorithm(algorithm, AlgorithmConfig(u_hat=0.5, r_hat=0.5, random_budget=0.3),
                          1, 1, 0).names
    if "c" not in names:
        return "mixed"
    return "resets_first" if names[0] == "c" else "teleops_first"


def _lex_positive(key: Sequence[float]) -> bool:
    """The allocator's eligibility of one key (``testbed.fleet.allocator.lex_positive``)."""
    for v in key:
        if v != 0:
            return v > 0
    return False


@dataclass
class Rates:
    """Events ``k`` of ``n`` trials per phase bin (grown as bins appear)."""

    k: list[int] = field(default_factory=list)
    n: list[int] = field(default_factory=list)

    def add(self, b: int, hit: bool) -> None:
        while len(self.n) <= b:
            self.k.append(0)
            self.n.append(0)
        self.n[b] += 1
        self.k[b] += bool(hit)

    def arrays(self, bins: int) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        k = np.zeros(bins)
        n = np.zeros(bins)
        k[:len(self.k)] = self.k[:bins]
        n[:len(self.n)] = self.n[:bins]
        return k, n

    def pooled(self) -> float:
        """The whole run's rate, Laplace's rule (the bins' prior mean)."""
        return (sum(self.k) + 1.0) / (sum(self.n) + 2.0)

    def draw(self, bins: int, replicates: int, rng: np.random.Generator
             ) -> npt.NDArray[np.float64]:
        """(R, bins) rates from each bin's Beta posterior, shrunk to the pooled rate."""
        k, n = self.arrays(bins)
        p = self.pooled()
        return rng.beta(k + PRIOR_BIN * p, n - k + PRIOR_BIN * (1.0 - p),
                        size=(replicates, bins))

    def draw_weighted(self, k: npt.NDArray[np.float64], n: npt.NDArray[np.float64],
                      rng: np.random.Generator) -> npt.NDArray[np.float64]:
        """As :meth:`draw`, from counts ``k``, ``n`` (R, bins) reweighted per replicate
        (:meth:`PlanFit.draw`'s bootstrap over runs); the prior stays the pooled one."""
        p = self.pooled()
        return rng.beta(k + PRIOR_BIN * p, n - k + PRIOR_BIN * (1.0 - p))

    def merge(self, other: Rates) -> None:
        for b, (k, n) in enumerate(zip(other.k, other.n, strict=True)):
            while len(self.n) <= b:
                self.k.append(0)
                self.n.append(0)
            self.k[b] += k
            self.n[b] += n

    def means(self, bins: int) -> npt.NDArray[np.float64]:
        k, n = self.arrays(bins)
        p = self.pooled()
        return (k + PRIOR_BIN * p) / (n + PRIOR_BIN)


@dataclass
class Outcomes:
    """Pushes per bin (or per human in bin 0): successes, violations, the rest."""

    counts: list[list[int]] = field(default_factory=list)

    def add(self, b: int, success: bool, violation: bool) -> None:
        while len(self.counts) <= b:
            self.counts.append([0, 0, 0])
        self.counts[b][0 if success else 1 if violation else 2] += 1

    def array(self, bins: int) -> npt.NDArray[np.float64]:
        out = np.zeros((bins, 3))
        for b, c in enumerate(self.counts[:bins]):
            out[b] = c
        return out

    def total(self) -> npt.NDArray[np.float64]:
        return np.array([sum(c[i] for c in self.counts) for i in range(3)], dtype=float)

    def merge(self, other: Outcomes) -> None:
        for b, c in enumerate(other.counts):
            while len(self.counts) <= b:
                self.counts.append([0, 0, 0])
            self.counts[b] = [x + y for x, y in zip(self.counts[b], c, strict=True)]


@dataclass
class Processes:
    """One run's counts of every arm process (the fit keeps each run's, and their sum)."""

    requests: Rates = field(default_factory=Rates)
    continues: Rates = field(default_factory=Rates)
    eligible: Rates = field(default_factory=Rates)
    policy: Outcomes = field(default_factory=Outcomes)


@dataclass
class HumanFit:
    """One human (by index, over the label's runs): what their rows showed."""

    index: int
    name: str
    on_site: bool = True
    """The person's place in the runs (``HumanProfile.where``): only on site resets."""
    pushes: Outcomes = field(default_factory=Outcomes)
    latency: list[int] = field(default_factory=list)
    """Per teleop with a push: steps from the assignment to the first push."""
    reset_steps: list[int] = field(default_factory=list)
    """Per confirmed reset: the steps it took (``first.steps + 1``)."""
    present: int = 0
    away: int = 0


@dataclass
class Draws:
    """One posterior draw per replicate (R): the fitted processes' parameters, per
    fitted human (H) where they are a person's; :mod:`testbed.planning.plan_sim`
    maps the planned humans onto them."""

    trouble: TroubleDraws
    """Each arm's requests and policy pushes: calm or in trouble (:mod:`plan_trouble`)."""
    eligible: npt.NDArray[np.float64]
    """(R, B) P(a violating arm's key > 0): used only for keys without ``c``."""
    human: npt.NDArray[np.float64]
    """(R, H, 3) per teleop push of human h."""
    available: npt.NDArray[np.float64]
    """(R, H) the chance human h can take new work at a step."""
    latency_values: npt.NDArray[np.int64]
    latency_cdf: npt.NDArray[np.float64]
    """(R, H, S): per human, a distribution over ``latency_values`` (Bayesian bootstrap)."""
    reset_values: npt.NDArray[np.int64]
    reset_cdf: npt.NDArray[np.float64]


@dataclass
class PlanFit:
    """What one algorithm's runs say the fleet's humans face (module doc)."""

    label: str
    algorithm: str
    runs: list[Path]
    points: list[tuple[int, int]]
    """Each run's (N arms, M humans)."""
    steps: int
    """The longest run's steps."""
    t_T: int
    t_R: int
    t_I: int
    bin_steps: int
    order: KeyOrder
    initial_period: bool
    """C.U.R.: a violating arm's key is -1 (no human) while t < t_I."""
    requests: Rates = field(default_factory=Rates)
    continues: Rates = field(default_factory=Rates)
    eligible: Rates = field(default_factory=Rates)
    policy: Outcomes = field(default_factory=Outcomes)
    humans: list[HumanFit] = field(default_factory=list)
    per_run: list[Processes] = field(default_factory=list)
    """Each run's own counts of the processes above (their sum), for the bootstrap."""
    sequences: list[ArmSequences] = field(default_factory=list)
    """Each run's arms, for the trouble model's fit."""
    trouble: TroubleCounts | None = None
    """The trouble model's expected counts at its fit (:func:`fit_trouble`), summed."""
    trouble_runs: list[TroubleCounts] = field(default_factory=list)
    """The same per run, for the bootstrap."""
    trouble_loglik: float = float("nan")
    """The trouble model's log-likelihood per observed step at its fit."""
    measured: list[dict[str, float]] = field(default_factory=list)
    """Per run: the plan's metrics as the run measured them (:func:`run_metrics`)."""
    notes: list[str] = field(default_factory=list)

    @property
    def bins(self) -> int:
        return max(1, math.ceil(self.steps / self.bin_steps))

    @property
    def own(self) -> tuple[int, int]:
        """The runs' own (N, M): the commonest, the first run's on a tie."""
        return Counter(self.points).most_common(1)[0][0]

    def draw(self, replicates: int, rng: np.random.Generator) -> Draws:
        """Every fitted parameter, redrawn from its posterior once per replicate.

        With two runs or more, the arms' processes are drawn after a Bayesian bootstrap
        over the runs (Rubin 1981): each replicate reweights the runs by Dirichlet(1, ...,
        1) x K weights, then draws from the posterior of the reweighted counts. Why: the
        run is the independent unit (a seed's cube placements and the policy it grows
        hold for the whole run); on the twin the fit's 4 runs' request rates were 0.19 to
        0.30 where the binomial error of one run is 0.01, and a posterior that pooled
        every arm-step alike gave intervals too narrow for a new run's seeds."""
        r = replicates
        w = (rng.dirichlet(np.ones(len(self.per_run)), size=r) * len(self.per_run)
             if len(self.per_run) >= 2 else None)
        pol_total = self.policy.total()
        pol_mean = (pol_total + 1.0) / (pol_total.sum() + 3.0)
        humans = self.humans or [HumanFit(0, unnamed_human(0))]
        pool = sum((h.pushes.total() for h in humans), np.zeros(3))
        pool_mean = (pool + POOL_PUSHES * pol_mean) / (pool.sum() + POOL_PUSHES)
        human = np.stack([h.pushes.total() + PRIOR_PUSHES * pool_mean for h in humans])
        lat_values, lat_cdf = _times([h.latency for h in humans], 0, r, rng)
        reset_values, reset_cdf = _times([h.reset_steps for h in humans], self.t_R, r, rng)
        if self.trouble is None:
            self.fit_trouble()
        assert self.trouble is not None
        return Draws(
            trouble=draw_trouble(self.trouble, self.trouble_runs, w, r, rng),
            eligible=self._rates("eligible", w, r, rng),
            human=_dirichlet(np.broadcast_to(human, (r, len(humans), 3)), rng),
            available=np.stack([_availability(h, r, rng) for h in humans], axis=1),
            latency_values=lat_values, latency_cdf=lat_cdf,
            reset_values=reset_values, reset_cdf=reset_cdf)

    def fit_trouble(self) -> None:
        """The trouble model's EM over the runs' arms (:func:`plan_trouble.fit_trouble`)."""
        self.trouble, self.trouble_runs, self.trouble_loglik = fit_trouble(
            self.sequences, self.bin_steps, self.bins)

    def _rates(self, name: str, w: npt.NDArray[np.float64] | None, r: int,
               rng: np.random.Generator) -> npt.NDArray[np.float64]:
        """(R, B) draws of one rate: pooled, or over reweighted runs."""
        pooled: Rates = getattr(self, name)
        if w is None:
            return pooled.draw(self.bins, r, rng)
        k, n = zip(*(getattr(p, name).arrays(self.bins) for p in self.per_run), strict=True)
        return pooled.draw_weighted(w @ np.stack(k), w @ np.stack(n), rng)


def _dirichlet(alpha: npt.NDArray[np.float64], rng: np.random.Generator
               ) -> npt.NDArray[np.float64]:
    """Dirichlet draws over the last axis (numpy's own takes one alpha vector only)."""
    g = rng.gamma(alpha)
    return g / g.sum(axis=-1, keepdims=True)


def _availability(h: HumanFit, replicates: int, rng: np.random.Generator
                  ) -> npt.NDArray[np.float64]:
    """Jeffreys' Beta(1/2, 1/2) posterior; 1 for a human no row ever counted."""
    if h.present + h.away == 0:
        return np.ones(replicates)
    return rng.beta(h.present + 0.5, h.away + 0.5, size=replicates)


def _times(per_human: Sequence[Sequence[int]], default: int, replicates: int,
           rng: np.random.Generator) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    """Per human a distribution over the observed times, per replicate: a Dirichlet with
    weight 1 on each of their own observations and ``PRIOR_TIMES`` spread over the pool's
    (the Bayesian bootstrap, shrunk as ``testbed.fleet.operators`` shrinks a time).
    Without any observation, the ``default`` (0 for a latency, t_R for a reset)."""
    pool = [v for obs in per_human for v in obs] or [default]
    values = np.array(sorted(set(pool)), dtype=np.int64)
    where = {int(v): i for i, v in enumerate(values)}
    alpha = np.zeros((len(per_human), values.size))
    for h, obs in enumerate(per_human):
        for v in obs:
            alpha[h, where[int(v)]] += 1.0
        for v in pool:
            alpha[h, where[int(v)]] += PRIOR_TIMES / len(pool)
    g = rng.gamma(np.broadcast_to(alpha, (replicates, *alpha.shape)))
    cdf = np.cumsum(g / g.sum(axis=-1, keepdims=True), axis=-1)
    cdf[..., -1] = 1.0
    return values, cdf


# ---- reading runs ---------------------------------------------------------------------
@dataclass(frozen=True)
class _Run:
    path: Path
    label: str
    algorithm: str
    rows: list[dict[str, Any]]
    num_humans: int
    names: list[str]
    params: dict[str, Any]
    """The run's ``[algorithm]`` table."""
    on_site: list[bool]
    """Per human: on site (config.toml's ``[[humans.people]]`` ``where``; all before it)."""


def _load(path: Path) -> _Run | str:
    """A finished training run, or why it is left out (one reason, the same words for
    every run it fits: the notes group by it)."""
    meta = json.loads((path / "run.json").read_text()) if (path / "run.json").exists() else {}
    status = meta.get("status")
    if status not in (None, "complete"):
        return f"unfinished ({status}; resume it with testbed trial --resume)"
    opts = meta.get("options", {})
    cfg_path = path / "config.toml"
    config = tomllib.loads(cfg_path.read_text()) if cfg_path.exists() else {}
    params = config.get("algorithm", {})
    label = str(opts.get("label") or opts.get("algorithm") or params.get("name") or "cur")
    if opts.get("evaluate") or label.startswith(EVAL_PREFIX):
        return "evaluations (their humans only reset)"
    algorithm = str(opts.get("algorithm") or params.get("name") or label)
    humans = config.get("humans", {})
    count = int(humans.get("count", 2))
    names = display_names(path, humans, count)
    people = humans.get("people") or []
    on_site = ([p.get("where", "on_site") != "remote" for p in people]
               if len(people) == count else [True] * count)
    rows = read_steps(path / "steps.jsonl")
    if not rows:
        return "no steps"
    return _Run(path, label, algorithm, rows, count, names, params, on_site)


def fit_runs(paths: Iterable[Path], bin_steps: int = BIN_STEPS
             ) -> tuple[list[PlanFit], list[str]]:
    """One :class:`PlanFit` per label over the finished runs in ``paths`` (run folders),
    in the order the labels first come; and one note per run left out."""
    fits: dict[str, PlanFit] = {}
    left: dict[str, list[str]] = {}
    for path in paths:
        run = _load(path)
        if isinstance(run, str):
            left.setdefault(run, []).append(path.name)
            continue
        fit = fits.get(run.label)
        if fit is None:
            defaults = AlgorithmConfig()
            t_I = int(run.params.get("t_I", defaults.t_I))
            fit = fits[run.label] = PlanFit(
                label=run.label, algorithm=run.algorithm, runs=[], points=[], steps=0,
                t_T=int(run.params.get("t_T", defaults.t_T)),
                t_R=int(run.params.get("t_R", defaults.t_R)), t_I=t_I, bin_steps=bin_steps,
                order=key_order(run.algorithm),
                initial_period=run.algorithm == "cur" and t_I > 0)
        elif (int(run.params.get("t_T", fit.t_T)), int(run.params.get("t_R", fit.t_R))) != (
                fit.t_T, fit.t_R):
            fit.notes.append(f"{path.name}: its t_T/t_R differ from the first run's; "
                             f"the plan uses t_T={fit.t_T}, t_R={fit.t_R}")
        if run.params.get("operators") == "matched" and not fit.notes:
            fit.notes.append('Its runs were matched (algorithm.operators = "matched"); '
                             "the plan replays blind Algorithm 1, so who gets which arm "
                             "may differ.")
        _count(fit, run)
    for fit in fits.values():
        fit.fit_trouble()
    notes = [f"{len(names)} run(s) left out, {why}: " + ", ".join(names[:4])
             + (f" and {len(names) - 4} more" if len(names) > 4 else "")
             for why, names in left.items()]
    if not fits:
        raise ConfigError("RUN_OR_PROTOCOL_DIR: no finished run to fit"
                          + (f" ({'; '.join(notes)})" if notes else ""))
    return list(fits.values()), notes


def _count(fit: PlanFit, run: _Run) -> None:
    """Add one run's rows to its label's fit; record what it measured."""
    n = max(len(r["robots"]) for r in run.rows)
    fit.runs.append(run.path)
    fit.points.append((n, run.num_humans))
    fit.steps = max(fit.steps, len(run.rows))
    while len(fit.humans) < run.num_humans:
        h = len(fit.humans)
        fit.humans.append(HumanFit(h, run.names[h], run.on_site[h]))
    counter = _RunCounter(fit, run.num_humans)
    for row in run.rows:
        counter.row(row)
    fit.per_run.append(counter.proc)
    fit.sequences.append(arm_sequences(run.rows))
    for name in ("requests", "continues", "eligible", "policy"):
        getattr(fit, name).merge(getattr(counter.proc, name))
    fit.measured.append(run_metrics(run.rows, run.num_humans, n, counter.requests,
                                    counter.served))
    if not sum(fit.requests.n) + sum(fit.continues.n) and not fit.notes:
        fit.notes.append("Its rows carry no keys (written before keys were recorded): "
                         "the teleop request rate is the prior's 0.5, not a fit.")


class _RunCounter:
    """One pass over a run's rows: every process of the fit, and the run's requests."""

    def __init__(self, fit: PlanFit, num_humans: int) -> None:
        self.fit = fit
        self.num_humans = num_humans
        self.proc = Processes()
        """The run's own counts of the arms' processes (the humans' go to the fit)."""
        self.prev: dict[str, tuple[str, int]] = {}
        """Robot -> (mode, served) of the last row."""
        self.requests = 0
        self.served = 0

    def row(self, row: Mapping[str, Any]) -> None:
        fit = self.fit
        b = int(row["t"]) // fit.bin_steps
        away = set(row.get("away", []))
        for h in range(self.num_humans):
            fit.humans[h].present += h not in away
            fit.humans[h].away += h in away
        now: dict[str, tuple[str, int]] = {}
        for r in row["robots"]:
            mode = str(r["mode"])
            now[r["robot"]] = (mode, int(r.get("served") or 0))
            if mode in _SKIP:
                continue
            self._keys(r, mode, b)
            self._pushes(r, mode, b)
        self.prev = now

    def _keys(self, r: Mapping[str, Any], mode: str, b: int) -> None:
        """The request processes: what the arm's key asked for, where it mattered."""
        key = r.get("key")
        if not key:
            return
        asked = _lex_positive(key)
        pm, ps = self.prev.get(r["robot"], ("autonomous", 0))
        if mode in _IDLE:  # violating: could it get a person at all?
            if mode == "idle" or r.get("served") == 0:
                self.proc.eligible.add(b, asked)
            return
        t_T, t_R = self.fit.t_T, self.fit.t_R
        if (pm == "teleop" and ps + 1 < t_T) or (pm == "reset" and ps + 1 < t_R):
            return  # held: its key decided nothing
        (self.proc.continues if pm == "teleop" else self.proc.requests).add(b, asked)
        if asked:
            self.requests += 1
            self.served += mode == "teleop"

    def _pushes(self, r: Mapping[str, Any], mode: str, b: int) -> None:
        """Pushes and their outcomes; a human's first actions (as ``report_humans``)."""
        pushed = r.get("action") is not None
        if mode == "autonomous":
            if pushed:
                self.proc.policy.add(b, bool(r["success"]), bool(r["violation"]))
            return
        h = r.get("human")
        if h is None or not 0 <= int(h) < self.num_humans:
            return
        person = self.fit.humans[int(h)]
        if mode == "teleop" and pushed:
            person.pushes.add(0, bool(r["success"]), bool(r["violation"]))
        first = r.get("first")
        if first is not None:
            steps = int(first["steps"])
            if mode == "reset":
                person.reset_steps.append(steps + 1)
            else:
                person.latency.append(steps)


def run_metrics(rows: Sequence[Mapping[str, Any]], num_humans: int, num_robots: int,
                requests: int, served: int) -> dict[str, float]:
    """The plan's metrics (``METRICS``) of one run as its rows measured them; the
    simulation computes each the same way (``plan_sim``)."""
    s = summarize(rows, algorithm="", num_humans=num_humans, num_robots=num_robots)
    idle = sum(r["mode"] == "idle" for row in rows for r in row["robots"])
    steps = len(rows)
    return {
        "successes": float(s["successes"]), "hard_resets": float(s["hard_resets"]),
        "idle_time": float(s["idle_time"]), "human_actions": float(s["human_actions"]),
        "rohe": float(s["rohe"]),
        "utilisation": s["human_actions"] / (num_humans * steps) if num_humans else 0.0,
        "wait": idle / s["hard_resets"] if s["hard_resets"] else 0.0,
        "unserved": 1.0 - served / requests if requests else 0.0,
    }
