"""Protocols: trials x algorithms x steps, run end to end, then reported.

A protocol file (``protocols/*.toml``) names the fleet (an inline ``[fleet]`` table,
validated like any config), the algorithms, the number of trials, their seeds and
steps. Runs go to ``<out>/<algorithm>-t<k>``; a run that already has its summary is
skipped and one without it is resumed, so a protocol interrupted on day one goes on
on day two with ``testbed protocol FILE`` again.

For the lab (``protocols/physical.toml``): ``prompt_when = "before_each_run"`` asks the
operator to put the cubes back before EVERY run (a caller such as ``testbed rehearse``
passes ``before_run`` instead of a person), and ``order = "counterbalanced"`` runs the
algorithms in a different, balanced order in each trial (a seeded Williams Latin
square), so no algorithm always meets the freshest cubes or the most tired operator.
Each run's run.json records its trial, its position and the trial's order. A run the
operator stopped with Esc stays ``stopped`` (no summary, left out of the report); the
protocol stops there and goes on from it when run again.

With ``until = { reference = "cur", metric = "rohe", alpha = 0.05, max_trials = 12 }``
(:class:`Until`) ``trials`` is the minimum: after each complete trial an anytime-valid
test per algorithm against the reference (:mod:`testbed.results.sequential`) decides
whether to run one more, up to ``max_trials``; each trial's e-values go to
``<out>/sequential.json`` and the report's sequential table. The decision is recomputed
from the finished runs, so running the file again resumes where it stopped, and a
larger ``max_trials`` continues it. Without ``until``, exactly the ``trials`` trials.

Over 450 lines, on purpose: a protocol's file model (ways, order, until) and its run
(trials, evaluations, resume, the report) are one lifecycle; a sweep's point is in
``sweep_point.py``, the sequential test in ``sequential.py``.
"""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from testbed.core.backend_registry import backend_of
from testbed.core.config import ConfigError, FieldProblem, _one_line, validation_context
from testbed.core.hosts import Hosts
from testbed.experiments.fleet_config import FleetConfig, require_protocol
from testbed.experiments.hooks import TrialHooks, as_hooks
from testbed.experiments.pretraining import pretrain_critics
from testbed.experiments.sweep_point import SweepPoint
from testbed.fleet.algorithms import ALGORITHM_NAMES
from testbed.records.run_dir import RunDir, evaluated, evaluation_label
from testbed.results.report import (
    METRICS,
    PAPER_FIRST,
    Report,
    run_summary,
    write_report,
)

if TYPE_CHECKING:
    from testbed.core.host_config import HostConfig
    from testbed.core.humans import Humans
    from testbed.experiments.trial import TrialOptions
    from testbed.fleet.loop import StepOutcome
    from testbed.results.sequential import Decision


class Way(BaseModel):
    """``[ways.<name>]``: an algorithm run another way (issue 30: C.U.R. with learning by
    class, with operators the allocator knows), its fleet fields set as a sweep's grid
    sets them (dotted names under ``fleet``). A way is named in ``algorithms`` like an
    algorithm; its runs, report rows and pairs carry its name."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    algorithm: str
    set: dict[str, Any] = Field(default_factory=dict)
    """Fleet fields this way sets, e.g. ``{"learning.weighting" = "intervention"}``."""


class Until(BaseModel):
    """``until = {...}``: run trials until every algorithm's comparison with
    ``reference`` on ``metric`` is settled at ``alpha`` (an anytime-valid test,
    :mod:`testbed.results.sequential`), or cannot be within ``max_trials``; the
    protocol's ``trials`` is then the minimum."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    reference: str = PAPER_FIRST
    metric: str = "rohe"
    alpha: float = Field(0.05, gt=0, lt=1)
    """The family-wise alpha, split by Bonferroni over :meth:`comparisons`."""
    max_trials: int = Field(12, ge=1, le=100)
    primary: str | None = None
    """The algorithm whose difference from ``reference`` on ``metric`` is the primary
    endpoint: the decision waits for it alone, the other pairs are secondary (reported,
    flagged, no sequential claim). None (protocols before it): every pair is primary."""
    family: dict[str, Annotated[int, Field(ge=1)]] = Field(default_factory=dict)
    """Other protocols (by name) whose primary comparisons share this one's reference
    runs, each with how many it has: they split alpha with this one's. Empty: this
    protocol's primaries alone."""

    def primaries(self, algorithms: list[str]) -> list[str]:
        """The primary pairs (by algorithm): ``primary``, else every algorithm but the
        reference."""
        if self.primary is not None:
            return [self.primary]
        return [a for a in algorithms if a != self.reference]

    def comparisons(self, algorithms: list[str]) -> int:
        """The family's primary comparisons: this protocol's and ``family``'s."""
        return len(self.primaries(algorithms)) + sum(self.family.values())

    def per_comparison_alpha(self, algorithms: list[str]) -> float:
        """``alpha / comparisons`` (Bonferroni): the alpha each pair is tested at."""
        return self.alpha / self.comparisons(algorithms)

    @field_validator("metric")
    @classmethod
    def _metric(cls, v: str) -> str:
        if v not in METRICS:
            raise ValueError(f"unknown metric {v!r}; use {', '.join(METRICS)}")
        return v


class Protocol(BaseModel):
    # defer_build: its fleet's hosts are a union of the installed backends (core/host_config.py)
    model_config = ConfigDict(extra="forbid", frozen=True, defer_build=True)

    name: str
    trials: int = Field(3, ge=1, le=100)
    algorithms: list[str] = Field(default_factory=lambda: ["bc", "random", "fleet-ed", "cur"])
    steps: int = Field(250, ge=1)
    seeds: list[int] | None = None
    out: str = "runs/protocol"
    humans: Literal["scripted", "gui", "web"] = "scripted"
    prompt_when: Literal["never", "between_trials", "before_each_run"] = "never"
    """When the operator is asked to put the cubes back (``prompt``): never, before
    each trial but the first, or before every run (algorithm x trial)."""
    prompt: str = "Put every cube back near the centre of its workspace, then press Enter."
    order: Literal["fixed", "counterbalanced"] = "fixed"
    """``fixed``: every trial runs ``algorithms`` in the given order; ``counterbalanced``:
    each trial a row of a Williams Latin square seeded from ``seeds`` (see run_order)."""
    evaluate_steps: int = Field(200, ge=0)
    """The paper's evaluation (8.3.4, Table 2): after each run, its final policy alone for
    this many steps, humans for hard resets only, as run ``eval-<algorithm>-t<k>``
    (report row ``eval:<algorithm>``, the report's second table). 0: none."""
    evaluate_expert: bool = True
    """With ``evaluate_steps``: also ``eval-expert-t<k>``, every arm driven by the twin's
    scripted expert (the paper's expert row; twin hosts only)."""
    fleet: FleetConfig = Field(default_factory=FleetConfig)
    ways: dict[str, Way] = Field(default_factory=dict)
    """Algorithms run another way (:class:`Way`), by the name ``algorithms`` gives them."""
    evaluate_start: bool = False
    """With ``evaluate_steps``: also ``eval-theta0-t<k>``, the policy every run of trial
    k starts from (theta_0), so the report can say what each run's humans taught: the
    learning gain per human action, (eval successes - theta_0's) / human actions."""
    until: Until | None = None
    """Stop when the answer is settled (:class:`Until`); None: exactly ``trials``."""
    pretrain_per_trial: bool = Field(False, strict=True)
    """Each trial pretrains its own theta_0 from its seed (own demonstrations, own
    initialisation, cached per seed), so leaving one theta_0 out of the failure head's
    fit holds out a policy (issue 45, item 1); false: every trial starts from one theta_0
    (``PRETRAIN_SEED``), the algorithms' fair comparison within a trial either way."""

    @model_validator(mode="before")
    @classmethod
    def _legacy_prompt(cls, data: Any) -> Any:
        """``prompt_between_trials = true`` (older protocol files) still works."""
        if isinstance(data, dict) and "prompt_between_trials" in data:
            data = dict(data)
            legacy = data.pop("prompt_between_trials")
            if not isinstance(legacy, bool):
                raise ValueError("prompt_between_trials must be true or false; "
                                 "prefer prompt_when")
            if legacy and "prompt_when" not in data:
                data["prompt_when"] = "between_trials"
        return data

    @model_validator(mode="after")
    def _check(self) -> Protocol:
        for name, way in self.ways.items():
            if name in ALGORITHM_NAMES or name in ("expert", START):
                raise ValueError(f"ways.{name}: the name of an algorithm; name the way "
                                 "otherwise (e.g. cur-weighted)")
            if way.algorithm not in ALGORITHM_NAMES:
                raise ValueError(f"ways.{name}.algorithm: unknown algorithm "
                                 f"{way.algorithm!r}; use {', '.join(ALGORITHM_NAMES)}")
            try:
                self.fleet_of(name)
            except ConfigError as exc:
                raise ValueError(f"ways.{name}.set: {exc}") from None
        bad = [a for a in self.algorithms if a not in ALGORITHM_NAMES and a not in self.ways]
        if bad:
            raise ValueError(f"unknown algorithm {bad[0]!r}; use {', '.join(ALGORITHM_NAMES)}"
                             " or a way of [ways]")
        if self.pretrain_per_trial and self.seeds is not None \
                and len(set(self.seeds)) < len(self.seeds):
            raise ValueError("pretrain_per_trial: seeds must differ (a trial's theta_0 is "
                             "pretrained from its seed)")
        if self.until is not None:
            self._check_until(self.until)
        elif self.seeds is not None and len(self.seeds) != self.trials:
            raise ValueError("seeds must have one seed per trial")
        match = self.fleet.algorithm.budget_match
        if (match is not None and "random" in self.algorithms
                and (match not in self.algorithms or match == "random")):
            raise ValueError(
                f"fleet.algorithm.random_budget = 'match:{match}': {match!r} must be "
                "another of the protocol's algorithms (its run sets Random's budget)")
        return self

    def _check_until(self, until: Until) -> None:
        if until.reference not in self.algorithms:
            raise ValueError(f"until.reference: {until.reference!r} is not one of the "
                             f"algorithms ({', '.join(self.algorithms)})")
        if len(self.algorithms) < 2:
            raise ValueError("until: needs at least two algorithms (one against the "
                             "reference)")
        if until.max_trials < self.trials:
            raise ValueError(f"until.max_trials ({until.max_trials}) is below trials "
                             f"({self.trials}), the minimum")
        if until.primary is not None and (until.primary not in self.algorithms
                                          or until.primary == until.reference):
            others = [a for a in self.algorithms if a != until.reference]
            raise FieldProblem("until.primary", f"{until.primary!r} is not one of the "
                               f"algorithms compared with {until.reference!r}; use one of "
                               f"{', '.join(others)} (or leave it out: every pair primary)")
        if self.name in until.family:
            raise FieldProblem("until.family", f"names this protocol ({self.name!r}); "
                               "list only the other protocols sharing its reference runs")
        if self.seeds is not None and len(self.seeds) < self.trials:
            raise ValueError("seeds must have one seed per trial (with until: at least "
                             "trials, the minimum; trials beyond the list get seeds after "
                             "its largest)")

    @property
    def max_trials(self) -> int:
        """The most trials this protocol runs: ``until.max_trials``, else ``trials``."""
        return self.until.max_trials if self.until is not None else self.trials

    def algorithm_of(self, name: str) -> str:
        """The algorithm a name of ``algorithms`` runs (a way's, or the name itself)."""
        way = self.ways.get(name)
        return way.algorithm if way is not None else name

    def fleet_of(self, name: str) -> FleetConfig:
        """The fleet a name of ``algorithms`` runs: ``fleet``, with a way's fields set."""
        way = self.ways.get(name)
        if way is None or not way.set:
            return self.fleet
        return SweepPoint(dict(way.set)).apply(self.fleet)

    def theta0_critics(self) -> list[str]:
        """The critics theta_0 is pretrained with (:func:`pretrain_critics`): what the
        algorithm each name runs reads (a way's name is no algorithm), and the goal
        critic where a way learns by advantage."""
        return pretrain_critics([self.algorithm_of(a) for a in self.algorithms],
                                ["advantage" if self.fleet_of(a).learning.by_advantage
                                 else "other" for a in self.algorithms])

    def evaluated(self) -> list[str]:
        """What each trial's evaluations evaluate (``_evaluate_all``): every algorithm's
        final policy, theta_0 (``START``) with ``evaluate_start``, the twin's expert with
        ``evaluate_expert`` on simulated hosts; none without ``evaluate_steps``."""
        if self.evaluate_steps == 0:
            return []
        names = [*self.algorithms, *([START] if self.evaluate_start else [])]
        if self.evaluate_expert and all(backend_of(h).capabilities.simulated
                                        for h in self.fleet.hosts):
            names.append("expert")
        return names

    def seed(self, k: int) -> int:
        """Trial ``k``'s seed: ``seeds[k]``, else ``k``. A trial beyond the listed seeds
        (only with ``until``) gets ``max(seeds) + 1 + (k - len(seeds))``: distinct from
        every listed seed and from each other, and the same whatever ``max_trials`` is,
        so raising it later keeps the trials already run."""
        if self.seeds is None:
            return k
        if k < len(self.seeds):
            return self.seeds[k]
        return max(self.seeds) + 1 + (k - len(self.seeds))

    def pretrain_seed(self, k: int) -> int | None:
        """The seed trial ``k``'s theta_0 is pretrained from: its own with
        ``pretrain_per_trial``, else None (the one every trial shares)."""
        return self.seed(k) if self.pretrain_per_trial else None

    def run_order(self, k: int) -> list[str]:
        """The algorithms of trial ``k`` in the order they run.

        Counterbalanced: trial k takes row k of a Williams Latin square over the
        algorithms (rows shuffled and algorithms relabelled by an RNG seeded from the
        protocol's trial seeds), so over each block of rows every algorithm runs once
        in every position and, for an even count, follows every other one once; a
        rerun of the protocol gets the same orders.
        """
        if self.order == "fixed" or len(self.algorithms) < 2:
            return self._matched_first(list(self.algorithms))
        import numpy as np

        n = len(self.algorithms)
        rows = williams_square(n)
        seeds = [self.seed(j) & 0xFFFFFFFF for j in range(self.trials)]
        rng = np.random.default_rng(np.random.SeedSequence([0xC0B1A5, n, *seeds]))
        row_order = rng.permutation(len(rows))
        label = rng.permutation(n)
        row = rows[int(row_order[k % len(rows)])]
        return self._matched_first([self.algorithms[int(label[j])] for j in row])

    def _matched_first(self, order: list[str]) -> list[str]:
        """With ``random_budget = "match:<a>"``: Random moved right after ``a`` when it
        would run first (its budget is read from a's run of the same trial)."""
        match = self.fleet.algorithm.budget_match
        if match is None or "random" not in order or match not in order:
            return order
        if order.index("random") > order.index(match):
            return order
        order.remove("random")
        order.insert(order.index(match) + 1, "random")
        return order


START = "theta0"
"""The name of the policy every run of a trial starts from, in evaluation runs."""


def williams_square(n: int) -> list[list[int]]:
    """A Williams design: rows of a Latin square in which, for even ``n``, each symbol
    follows each other one exactly once; for odd ``n`` the square and its mirror (2n
    rows) together balance it."""
    first = [0]
    lo, hi = 1, n - 1
    for j in range(1, n):
        if j % 2:
            first.append(lo)
            lo += 1
        else:
            first.append(hi)
            hi -= 1
    rows = [[(v + i) % n for v in first] for i in range(n)]
    if n % 2:
        rows += [list(reversed(r)) for r in rows]
    return rows


def load_protocol(path: Path, *, check_files: bool = True) -> Protocol:
    """``check_files=False``: expand but do not require the hosts' key_file/known_hosts
    (a caller that rewrites the hosts, e.g. a rehearsal)."""
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the protocol file ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    require_protocol(data, path)
    try:
        return Protocol.model_validate(data, context=validation_context(check_files))
    except ValidationError as err:
        raise ConfigError(_one_line(err, str(path))) from None


def run_protocol(proto: Protocol, out: str | None = None, ask: bool = True, *,
                 hooks: TrialHooks | None = None, plan: bool = True) -> Report:
    """Run every (trial, algorithm) of ``proto`` not yet complete, then the report.

    ``proto.fleet`` is the fleet driven (a caller may rewrite it with ``model_copy``;
    a resumed run drives it too). ``ask``: show the console prompt (``prompt_when``).
    ``hooks`` (``testbed.experiments.hooks.TrialHooks``): ``before_run(name)`` before
    every run that starts or resumes (True: the cubes are back, so no prompt: the
    rehearsal's lab hand), each run's humans, a wrapper of each run's hosts (it must
    pass start/rest/close/reseed through: a ``HostsWrapper``), and every step, beside
    the progress bar.

    A run the operator stops (Esc) ends the protocol: the report then covers the
    finished runs and says which one is stopped; ``testbed protocol FILE`` again
    resumes it.

    With ``until``: after each complete trial, :func:`sequential_decision` says whether
    to run the next (at least ``trials``, at most ``until.max_trials``); the
    evaluations wait till the end and cover the trials run.

    ``plan``: first print what is left to do and how long it takes
    (``testbed.experiments.time_plan``; ``testbed protocol`` prints its own, naming
    its file).
    """
    from testbed.core.config import ConfigError

    hooks = hooks if hooks is not None else TrialHooks()
    folder = Path(out or proto.out)
    if plan:
        from testbed.experiments.time_plan import say_protocol_plan

        say_protocol_plan(proto, folder)
    folder.mkdir(parents=True, exist_ok=True)
    cache: dict[Path, dict[str, Any]] = {}
    done = 0
    while done < proto.max_trials:
        note = _run_trial(proto, folder, done, ask, hooks)
        if note is not None:  # a run was stopped (Esc)
            sys.stderr.write(note + "\n")
            try:
                return write_report([folder], folder)  # it names the stopped run
            except ConfigError:  # nothing finished yet
                return Report(folder, note + "\n", [], [note])
        done += 1
        if proto.until is not None and sequential_decision(proto, folder, done, cache).stop:
            break
    _evaluate_all(proto, folder, hooks, done)
    # with until, the report pairs against its reference, as the test did
    return write_report([folder], folder,
                        proto.until.reference if proto.until is not None else None)


def _run_trial(proto: Protocol, folder: Path, k: int, ask: bool, hooks: TrialHooks
               ) -> str | None:
    """Every run of trial ``k`` not yet complete, in its order; a note when one was
    stopped (Esc), else None."""
    from testbed.experiments.trial import STOPPED

    total = proto.max_trials * len(proto.algorithms)
    first_in_trial = True
    for position, algorithm in enumerate(proto.run_order(k)):
        index = k * len(proto.algorithms) + position + 1
        name = f"{algorithm}-t{k}"
        run = RunDir(folder / name)
        if run.summary.exists():
            continue
        what = "resume" if run.state.exists() else "start"
        if not hooks.before_run(name) and ask and _prompts(proto, k, first_in_trial):
            _prompt(f"run {index}/{total} ({what} {name}): {proto.prompt}")
        first_in_trial = False
        summary = run_protocol_run(proto, folder, k, algorithm, hooks=hooks)
        if summary.get("status") == STOPPED:
            return (f"protocol stopped: {name} was stopped at step "
                    f"{summary.get('stopped_at')}; run the protocol again to resume it")
    return None


def sequential_decision(proto: Protocol, folder: Path, done: int,
                        cache: dict[Path, dict[str, Any]] | None = None) -> Decision:
    """After ``done`` complete trials of ``proto`` (with ``until``) in ``folder``: every
    algorithm's difference from the reference on the metric in each, recomputed from
    its steps.jsonl as the report does, the stopping decision
    (:func:`testbed.results.sequential.decide`), and each trial's e-values written
    to ``folder/sequential.json``. ``cache``: summaries already read, by run folder."""
    from testbed.core.atomic import atomic_write_json
    from testbed.results.sequential import RECORD, decide, record

    until = proto.until
    if until is None:
        raise ValueError("sequential_decision: the protocol has no until")
    cache = {} if cache is None else cache
    values = {a: [_summary(folder / f"{a}-t{k}", cache)[until.metric] for k in range(done)]
              for a in proto.algorithms}
    ref = values[until.reference]
    diffs = {a: [float(x) - float(r) for x, r in zip(v, ref, strict=True)]
             for a, v in values.items() if a != until.reference}
    decision = decide(diffs, alpha=until.per_comparison_alpha(proto.algorithms),
                      min_trials=proto.trials, max_trials=until.max_trials,
                      primary=until.primaries(proto.algorithms))
    atomic_write_json(folder / RECORD, record(
        decision, reference=until.reference, metric=until.metric,
        seeds=[proto.seed(k) for k in range(done)], protocol=proto.name,
        family_alpha=until.alpha, family=until.family))
    if decision.stop:
        sys.stderr.write(f"protocol {proto.name}: stops after {done} trial(s): "
                         f"{decision.why} (e-values in {folder / RECORD})\n")
    return decision


def _summary(path: Path, cache: dict[Path, dict[str, Any]]) -> dict[str, Any]:
    """A finished run's metrics as the report reads them (``run_summary``), by folder."""
    if path not in cache:
        cache[path] = run_summary(path)
    return cache[path]


def _prompts(proto: Protocol, k: int, first_in_trial: bool) -> bool:
    """Whether the operator is asked to put the cubes back before this run (the first
    of trial ``k`` that runs: ``first_in_trial``)."""
    if proto.prompt_when == "before_each_run":
        return True
    return proto.prompt_when == "between_trials" and k > 0 and first_in_trial


def _evaluate_all(proto: Protocol, folder: Path, hooks: TrialHooks, trials: int) -> None:
    """The paper's evaluation of every final policy of the first ``trials`` trials (and
    the expert row on twins)."""
    for k in range(trials):
        order = proto.run_order(k)
        for algorithm in order:
            evaluate_run(proto, folder, algorithm, k, hooks)
        if proto.evaluate_start and order:
            evaluate_run(proto, folder, START, k, hooks, start_of=order[0])
        if proto.evaluate_expert and all(backend_of(h).capabilities.simulated
                                         for h in proto.fleet.hosts):
            evaluate_run(proto, folder, "expert", k, hooks)


def run_protocol_run(proto: Protocol, folder: Path, k: int, algorithm: str, *,
                     hooks: TrialHooks | None = None,
                     meta: dict[str, Any] | None = None) -> dict[str, Any]:
    """Run ``<algorithm>-t<k>`` of ``proto`` in ``folder`` (``run_named``: skipped when
    finished, resumed when checkpointed), Random's budget matched from its run of the
    same trial. ``meta``: extra run.json keys. The serial loop and a Ray task both
    call this."""
    from testbed.experiments.trial import TrialOptions

    cfg = proto.fleet_of(algorithm)
    order = proto.run_order(k)
    opts = TrialOptions(algorithm=proto.algorithm_of(algorithm), steps=proto.steps,
                        seed=proto.seed(k), out=str(folder), humans=proto.humans,
                        name=f"{algorithm}-t{k}", label=algorithm,
                        pretrain_critics=proto.theta0_critics(),
                        pretrain_seed=proto.pretrain_seed(k))
    run_meta: dict[str, Any] = {
        **(meta or {}),
        "protocol": {"name": proto.name, "trial": k, "position": order.index(algorithm),
                     "order": order, "ordering": proto.order}}
    run_cfg = cfg
    if (algorithm == "random" and cfg.algorithm.budget_match is not None
            and not RunDir(folder / opts.name).summary.exists()):
        matched = f"{cfg.algorithm.budget_match}-t{k}"
        budget = matched_budget(folder / matched, cfg.humans.count)
        run_meta["budget_matched"] = {"run": matched, "random_budget": budget}
        run_cfg = cfg.model_copy(update={"algorithm": cfg.algorithm.model_copy(
            update={"random_budget": budget})})
    return run_named(run_cfg, opts, folder, meta=run_meta, hooks=hooks,
                     host_configs=cfg.hosts)


def run_named(cfg: FleetConfig, opts: TrialOptions, folder: Path, *,
              meta: dict[str, Any], hooks: TrialHooks | None = None,
              host_configs: list[HostConfig] | None = None) -> dict[str, Any]:
    """The run ``folder/opts.name`` of a protocol or a sweep, under a progress bar:
    skipped when finished (``{"status": "complete", "skipped": True}``), resumed when it
    has a checkpoint (driving ``host_configs``, default the run's own hosts), else
    started afresh (a folder that died before its first checkpoint is discarded).
    Returns the trial's summary."""
    from testbed.experiments.progress import TrialProgress
    from testbed.experiments.trial import COMPLETE, run_trial

    run = RunDir(folder / (opts.name or opts.algorithm))
    if run.summary.exists():
        return {"status": COMPLETE, "skipped": True}
    resume = run.path if run.state.exists() else None
    if run.path.exists() and resume is None:
        _discard(run.path)
    with TrialProgress(opts.steps, cfg.humans.count, len(cfg.robot_names),
                       label=run.path.name) as bar:
        _, summary = run_trial(cfg, opts, resume=resume, hooks=as_hooks(bar, hooks),
                               meta=meta,
                               host_configs=host_configs if resume is not None else None)
    return summary


def evaluate_run(proto: Protocol, folder: Path, algorithm: str, k: int,
                 hooks: TrialHooks | None = None, *, start_of: str | None = None) -> None:
    """``eval-<algorithm>-t<k>``: the final policy of ``<algorithm>-t<k>`` alone for
    ``proto.evaluate_steps`` steps, C-prioritised hard resets only (``testbed evaluate``);
    skipped when done or disabled, redone when it died before finishing. ``start_of``:
    evaluate instead the policy run ``<start_of>-t<k>`` started from (``START``)."""
    from testbed.experiments.progress import TrialProgress
    from testbed.experiments.trial import TrialOptions, run_trial

    expert = algorithm == "expert"  # the twin's scripted expert: no run, no policy file
    source = RunDir(folder / f"{start_of or algorithm}-t{k}")
    policy = source.start_learner if start_of is not None else source.learner
    name = f"eval-{algorithm}-t{k}"
    run = RunDir(folder / name)
    if (proto.evaluate_steps == 0 or run.summary.exists()
            or not (expert or policy.exists())):
        return
    if run.path.exists():
        _discard(run.path)
    evaluates = ({"policy": None, "run": None, "algorithm": "expert"} if expert
                 else {**evaluated(policy), "algorithm": START} if start_of is not None
                 else evaluated(policy))
    opts = TrialOptions(algorithm="bc", steps=proto.evaluate_steps, seed=proto.seed(k),
                        out=str(folder), humans=proto.humans, policy=evaluates["policy"],
                        evaluate=True, name=name, label=evaluation_label(algorithm),
                        expert=expert)
    meta = {"evaluates": evaluates,
            "protocol": {"name": proto.name, "trial": k, "evaluation": True}}
    cfg = proto.fleet
    with TrialProgress(opts.steps, cfg.humans.count, len(cfg.robot_names), label=name) as bar:
        run_trial(cfg, opts, hooks=_EvaluationHooks(bar, hooks or TrialHooks()), meta=meta)


class _EvaluationHooks(TrialHooks):
    """An evaluation's hooks: its humans and hosts from the protocol's hooks, its
    progress on the bar; the protocol's ``on_step`` hears only the training runs."""

    def __init__(self, bar: TrialHooks, hooks: TrialHooks) -> None:
        self.bar, self.hooks = bar, hooks

    def humans(self, name: str) -> Humans | None:
        return self.hooks.humans(name)

    def wrap_humans(self, humans: Humans, run: RunDir) -> Humans:
        return self.hooks.wrap_humans(humans, run)

    def wrap_hosts(self, hosts: Hosts, run: RunDir) -> Hosts:
        return self.hooks.wrap_hosts(hosts, run)

    def on_phase(self, name: str, done: int, total: int) -> None:
        self.bar.on_phase(name, done, total)

    def on_step(self, outcome: StepOutcome) -> None:
        self.bar.on_step(outcome)


def matched_budget(run: Path, num_humans: int) -> float:
    """The fraction of humans busy in a finished run: human actions (teleop and reset
    arm-steps) / (humans x steps), read from its steps.jsonl. Random given it as its
    budget spends the same human effort (``RandomPriority`` keeps its effort on budget)."""
    from testbed.core.config import ConfigError
    from testbed.records.metrics import summarize
    from testbed.records.steps import read_steps

    rd = RunDir(run)
    if not rd.summary.exists():
        raise ConfigError(f"random_budget 'match:': {run} has not finished; the matched "
                          "algorithm runs before Random in each trial")
    summary = summarize(read_steps(rd.steps), algorithm="", num_humans=num_humans)
    effort = num_humans * summary["steps"]
    return min(1.0, summary["human_actions"] / effort) if effort else 0.0


def _discard(path: Path) -> None:
    """A run folder that died before its first checkpoint holds nothing worth keeping."""
    import shutil

    shutil.rmtree(path)


def _prompt(text: str) -> None:
    if not sys.stdin.isatty():
        sys.stderr.write(f"{text} (no terminal: going on)\n")
        return
    input(f"{text} ")


__all__: list[Any] = [
    "Protocol",
    "Until",
    "evaluate_run",
    "load_protocol",
    "matched_budget",
    "pretrain_critics",
    "run_named",
    "run_protocol",
    "sequential_decision",
    "williams_square",
]
