"""One trial end to end: its run folder, its learner, the loop, its records, teardown.

This is the thin script around ``FleetLoop`` (as LeRobot's record script around its
robot), in steps of one job each:

1. ``_open_run``: the run's folder, new (config.toml, run.json) or resumed (the
   checkpoint's step; steps.jsonl cut back to it);
2. ``_prepare``: the algorithm and the learner the first step acts with (theta_0,
   a trained policy, the resumed learner or the expert), thresholds given as
   quantiles resolved on it;
3. ``_run_steps``: the loop, one checkpoint per complete step, the records closed
   whatever happens;
4. ``_finish``: run.json's status, the summary.

``run_trial`` builds the hosts and humans (``testbed.experiments.build``), checks every
controller host read-only once the hosts answer, before step 1
(``testbed.experiments.controller_gate``: a FAULT refuses the trial, nothing moved),
runs those steps inside ``try/finally`` so that, whatever happens, the arms go to their
rest pose and the humans are closed, and ``--resume`` continues where a crash or a kill
left off.
run.json is written when the run opens (with the code it runs), once its hosts have
answered (which hosts), once it is prepared, and at the end.

Over 450 lines, on purpose: one trial in the order it happens (build, resume, pretrain,
run, finish), read top to bottom; theta_0 and resume are in ``learners.py``, hosts and
humans in ``build.py``.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from testbed.core.atomic import atomic_write_bytes, atomic_write_json
from testbed.core.config import ConfigError
from testbed.core.host_config import HostConfig
from testbed.core.hosts import Hosts, LoopHosts, hosts_info_of, stop_motion_of
from testbed.core.humans import Humans, HumansStopRequested
from testbed.core.interrupts import critical
from testbed.core.wrappers import HumansWrapper
from testbed.experiments.build import build_hosts, code_identity, make_humans, shared_cells
from testbed.experiments.checkpointer import CheckpointWriter
from testbed.experiments.controller_gate import (
    TrialRefused,
    controller_faults,
    controller_hosts,
)
from testbed.experiments.fleet_config import FleetConfig
from testbed.experiments.hooks import TrialHooks
from testbed.experiments.learners import (
    PRETRAIN_SEED,
    keep_demos,
    load_learner,
    name_fleet,
    pretrained_learner,
    resume_learner,
)
from testbed.experiments.web_links import links_for_run
from testbed.fleet.algorithms import Algorithm, get_algorithm
from testbed.fleet.loop import FleetLoop
from testbed.fleet.thresholds import SIGNAL, resolve_thresholds
from testbed.people.people_config import WebConsoleConfig
from testbed.records.metrics import summarize
from testbed.records.run_dir import RunDir, new_run_dir
from testbed.records.steps import RunWriter, read_steps, truncate_torn_tail
from testbed.records.store import FOLDER as DATA_FOLDER
from testbed.records.store import META as DATA_META
from testbed.records.store import RunData, RunDataWriter

LOG = logging.getLogger(__name__)

__all__ = ["COMPLETE", "REFUSED", "RUNNING", "STOPPED", "TrialOptions", "TrialRefused",
           "run_trial", "write_summary"]


@dataclass
class TrialOptions:
    algorithm: str
    steps: int
    seed: int
    out: str
    humans: str
    policy: str | None = None
    evaluate: bool = False
    name: str | None = None
    expert: bool = False
    """Every arm driven by the twin's scripted expert (the evaluation's expert row,
    ``testbed/experiments/expert.py``); with ``evaluate`` and algorithm ``bc``."""
    label: str | None = None
    """What the records call the run's algorithm (summary.json, the report's row);
    None: ``algorithm``. An evaluation is ``eval:<the evaluated run's algorithm>``, so
    it never lands in a training algorithm's row (it allocates as ``bc`` does)."""
    pretrain_critics: list[str] | None = None
    """The critics theta_0 is pretrained with (``"safety"``, ``"goal"``): a protocol
    sets the union over its algorithms, so they all share one theta_0. The trial's own
    algorithm's critics are always added (None: just those). The trial itself trains
    online only what its algorithm reads."""
    pretrain_seed: int | None = None
    """The seed theta_0 is pretrained from: None, the one every trial shares
    (``PRETRAIN_SEED``); a protocol with ``pretrain_per_trial`` gives the trial's seed,
    so each trial starts from a policy of its own (issue 45, item 1)."""


COMPLETE = "complete"
STOPPED = "stopped"
RUNNING = "running"
REFUSED = "refused"
"""run.json ``status``: ``running`` until the loop ends (also what a crash or a kill
leaves), ``stopped`` when the operator stopped it (Esc; resumable, no summary),
``complete`` when every step ran (summary.json written), ``refused`` when the
controllers' check before step 1 found a FAULT (run.json ``refused``: its lines)."""


@dataclass
class _Run:
    """A run's folder and what is known of it before its hosts start."""

    dir: RunDir
    cfg: FleetConfig
    """The fleet driven (``host_configs`` applied, thresholds resolved once prepared)."""
    written: FleetConfig
    """The fleet of config.toml: as given, never ``host_configs``' rewrite."""
    opts: TrialOptions
    meta: dict[str, Any]
    state: dict[str, Any] | None = None
    """The checkpoint resumed from (None: a new run)."""
    prior_rows: list[dict[str, Any]] = field(default_factory=list)

    @property
    def start(self) -> int:
        return 0 if self.state is None else int(self.state["t"]) + 1

    def save_meta(self, **update: Any) -> None:
        self.meta.update(update)
        self.dir.write_meta(self.meta)


def run_trial(
    cfg: FleetConfig,
    opts: TrialOptions,
    *,
    resume: Path | None = None,
    hooks: TrialHooks | None = None,
    hosts: Hosts | None = None,
    meta: Mapping[str, Any] | None = None,
    host_configs: Sequence[HostConfig] | None = None,
) -> tuple[RunDir, dict[str, Any]]:
    """Run (or resume) a trial; return its folder and its summary.

    ``hooks``: the run's humans (``hooks.humans(name)``; default: ``make_humans`` of
    ``opts.humans`` and the config's ``humans``), a wrapper of the hosts the trial
    builds (``hooks.wrap_hosts``), pretraining's progress and every step
    (``testbed.experiments.hooks``). The trial closes the humans. ``hosts``: drive
    these, already started, instead of building the fleet's (benchmarks); the caller
    closes them. ``meta``: extra keys for a new run's run.json (a protocol's trial
    index and algorithm order). ``host_configs``: drive these hosts instead of the
    run's (same host and arm names): a resumed protocol run takes the protocol's
    current fleet, e.g. the fresh ports of a rehearsal or a lab's edited addresses.

    The summary has ``status``: ``complete`` (summary.json written) or ``stopped``
    (the operator pressed Esc: run.json says ``stopped`` and the step; resume it with
    ``testbed trial --resume`` or by rerunning the protocol; no summary.json until
    it is finished). :class:`TrialRefused` (run.json ``refused``) when a controller
    host's check before step 1 found a FAULT: nothing moved.
    """
    hooks = hooks if hooks is not None else TrialHooks()
    run = _open_run(cfg, opts, resume, meta, host_configs)
    cfg, opts = run.cfg, run.opts
    humans = hooks.humans(run.dir.path.name)
    if humans is None:
        web = cfg.humans.web
        if opts.humans == "web":  # the links kept with the run and its folder of runs:
            # a resume, and every command of the day in that folder, give the same
            web = links_for_run(run.dir.path, web or WebConsoleConfig(), cfg.humans.count,
                                run.dir.path.parent)
        humans = make_humans(opts.humans, cfg.humans.count, web,
                             people=cfg.humans.profiles, seed=opts.seed,
                             robots=cfg.robot_names,
                             names=[p.name for p in cfg.humans.people],
                             resumed_at=run.start if resume is not None else None)
        humans = hooks.wrap_humans(humans, run.dir)
    own_hosts = hosts is None
    checked: Any = hosts  # what the controllers' check asks: the fleet, never a wrapper
    if hosts is None:
        checked = build_hosts(cfg, opts.seed + (run.start * 7919 if run.start else 0),
                              log_dir=run.dir.path / "hosts")
        hosts = hooks.wrap_hosts(checked, run.dir)
    _stop_motion_on_console_stop(humans, hosts)
    stopped_at: int | None = None
    passed = False  # the controllers' check: until it passes, nothing of this trial moved
    try:
        if own_hosts:
            hosts.start()
        try:
            _check_controllers(run, checked)
        except TrialRefused:
            _record_hosts(run, hosts)  # run.json names the controllers that refused
            run.save_meta()
            raise
        passed = True
        try:
            algorithm, learner, driven = _prepare(run, hosts, humans, hooks)
        except HumansStopRequested as stop:  # Esc while the demos were being collected
            LOG.warning("trial stopped by the operator before step %d: %s", run.start, stop)
            stopped_at = run.start
        if stopped_at is None:
            stopped_at = _run_steps(run, driven, humans, learner, algorithm, hooks)
        _record_hosts(run, hosts)  # a host that first answered during the steps
    finally:
        if own_hosts:
            try:
                if passed:  # before, nothing moved: a rest would move an arm the check
                    hosts.rest()  # refused (or was about to judge) where it stands
            finally:
                hosts.close()
        humans.close()
    return _finish(run, stopped_at)


def _check_controllers(run: _Run, fleet: Any) -> None:
    """Before step 1 (before any observation or push): the read-only check of every
    controller host (``testbed.experiments.controller_gate``; none: no cost). run.json
    ``controllers_checked`` says which hosts passed and how long it took; a FAULT
    refuses the trial: run.json says ``refused`` with the FAULT lines (no step, no
    checkpoint: a protocol run again starts the run afresh) and :class:`TrialRefused`
    carries them to the command, which prints them and exits 1."""
    checked = controller_hosts(run.cfg.hosts)
    if not checked:
        return
    t0 = time.monotonic()
    faults = controller_faults(fleet, run.cfg.hosts)
    took = round(time.monotonic() - t0, 3)
    if faults:
        LOG.error("trial refused before step %d (0-based): %s", run.start, "; ".join(faults))
        run.save_meta(status=REFUSED, refused=faults)
        raise TrialRefused(faults)
    LOG.info("controllers checked before step %d (0-based) in %.2f s: %s", run.start, took,
             ", ".join(h.name for h in checked))
    _record(run.meta, "controllers_checked", {"hosts": [h.name for h in checked],
                                              "seconds": took})
    run.save_meta()


def _stop_motion_on_console_stop(humans: Humans, hosts: Hosts) -> None:
    """A console's confirmed Stop stops the motions in flight too (``on_stop`` of
    ``gui.console_core.ConsoleCore``, through any humans wrappers): the trial itself
    stops at the step's end, but a push of seconds on a real arm must not run on."""
    inner: Any = humans  # a console, or any humans (only a console has ``on_stop``)
    while isinstance(inner, HumansWrapper):
        inner = inner.humans
    if hasattr(inner, "on_stop"):
        inner.on_stop = functools.partial(stop_motion_of, hosts)


def _open_run(cfg: FleetConfig, opts: TrialOptions, resume: Path | None,
              meta: Mapping[str, Any] | None,
              host_configs: Sequence[HostConfig] | None) -> _Run:
    """The run's folder: resumed from its checkpoint, or new; run.json says running."""
    if resume is not None:
        run = _resumed(resume)
    else:
        folder = new_run_dir(opts.out, opts.name or f"{opts.algorithm}-s{opts.seed}")
        folder.write_config(cfg)
        run = _Run(folder, cfg, cfg, opts,
                   {**(meta or {}), "options": opts.__dict__, "created": time.time(),
                    "status": RUNNING, "humans": _humans_record(cfg, opts)})
        _record(run.meta, "code", code_identity())
        run.save_meta()
    if host_configs is not None:
        run.cfg = _with_hosts(run.cfg, host_configs, run.dir.path)
    return run


def _humans_record(cfg: FleetConfig, opts: TrialOptions) -> dict[str, Any]:
    """run.json ``humans``: who answered the interventions, by index: each human's name
    (never a secret: a web console's tokens are elsewhere and never written) and, for
    scripted humans, their profile (testbed/people/people_config.py ``HumanProfile``)."""
    scripted = opts.humans == "scripted"
    return {"kind": opts.humans, "people": [
        p.model_dump() if scripted else {"name": p.name, "where": p.where}
        for p in cfg.humans.profiles]}


def _resumed(path: Path) -> _Run:
    """A run folder with a checkpoint, its steps past the checkpoint dropped."""
    folder = RunDir(path)
    cfg = folder.read_config(FleetConfig)
    meta = folder.read_meta()
    opts = TrialOptions(**meta["options"])
    if not folder.state.exists():
        raise ConfigError(f"{path}: no checkpoint yet (state.json); start a new trial")
    state = json.loads(folder.state.read_text())
    truncate_torn_tail(folder.steps)
    prior = [r for r in read_steps(folder.steps) if r["t"] <= state["t"]]
    _rewrite_steps(folder.steps, prior)
    meta.update(status=RUNNING, resumed=[*meta.get("resumed", []), time.time()])
    meta.pop("stopped_at", None)
    _record(meta, "code", code_identity())  # this session's, beside the first's
    run = _Run(folder, cfg, cfg, opts, meta, state, prior)
    run.save_meta()
    return run


def _record(meta: dict[str, Any], key: str, value: dict[str, Any],
            merge: Callable[[Any, dict[str, Any]], dict[str, Any]] | None = None) -> None:
    """run.json ``key`` (``code``, ``hosts``) for this session. The session that opened
    the run writes ``key``; each resumed session k appends its own entry
    ``{"session": k, key: value}`` to ``resumed_<key>`` (k as in ``resumed`` and the
    data store's frames), so what the first session recorded is kept and every session
    says what ran its steps, even when it is the same. ``merge``: how to combine with
    what this session recorded before (its hosts that answered late)."""
    session = len(meta.get("resumed", []))
    slot = meta
    if session:
        history = meta.setdefault(f"resumed_{key}", [])
        if not history or history[-1].get("session") != session:
            history.append({"session": session})
        slot = history[-1]
    old = slot.get(key)
    slot[key] = value if merge is None or old is None else merge(old, value)


def _first_answers(old: dict[str, Any], new: dict[str, Any]) -> dict[str, Any]:
    """Each host as it first answered in this session; one that had not answered yet
    (``build`` None) as it is now."""
    return {name: old[name] if (old.get(name) or {}).get("build") else entry
            for name, entry in new.items()}


def _record_hosts(run: _Run, hosts: LoopHosts) -> None:
    """run.json ``hosts``: each host of the fleet as its agent said when it answered
    (``hosts_info_of``; never a credential); nothing for hosts that cannot say (an
    in-process double), rather than a guess."""
    info = hosts_info_of(hosts)
    if info is not None:
        _record(run.meta, "hosts", info, merge=_first_answers)


def _algorithm(run: _Run) -> Algorithm:
    """The run's algorithm; thresholds still given as quantiles set to 0.0 (one the
    algorithm does not read, or one not resolved yet: ``_prepare`` rebuilds it then)."""
    params = run.cfg.algorithm
    placeholders = params.model_copy(update=dict.fromkeys(params.quantile_thresholds, 0.0))
    return get_algorithm(run.opts.algorithm, placeholders, len(run.cfg.robot_names),
                         run.cfg.humans.count, run.opts.seed, run.cfg.monitor,
                         on_site=run.cfg.humans.on_site)


def _prepare(run: _Run, hosts: Hosts, humans: Humans, hooks: TrialHooks
             ) -> tuple[Algorithm, Any, Hosts]:
    """The algorithm, the learner the first step acts with, and the hosts the loop
    drives (the expert row wraps them). Thresholds given as quantiles are resolved on
    the learner, those the algorithm reads (BC reads neither); unread ones stay as given
    in config.toml. run.json gets the hosts (at once: pretraining may take minutes),
    the thresholds and the numerics (threads etc.)."""
    _record_hosts(run, hosts)
    run.save_meta()
    algorithm = _algorithm(run)
    pending = {k: q for k, q in run.cfg.algorithm.quantile_thresholds.items()
               if SIGNAL[k] in algorithm.spec.reads}
    hosts, learner = _starting_learner(run, algorithm, hosts, humans, hooks)
    name_fleet(learner, run.cfg)  # the loop's labels come by human index: whose
    if pending:  # a new run (a resumed one reads the resolved config back)
        run.cfg, resolved = resolve_thresholds(run.cfg, learner, only=pending)
        run.dir.write_config(run.written.model_copy(update={"algorithm": run.cfg.algorithm}))
        run.meta["thresholds"] = resolved
        algorithm = _algorithm(run)
    # whatever theta_0 had trained: from here on only what this algorithm reads
    learner.set_parts(train=algorithm.spec.train_parts, read=algorithm.spec.critics)
    if callable(getattr(learner, "numerics", None)):  # threads etc., for the lab
        run.meta["numerics"] = learner.numerics()
    run.save_meta()
    return algorithm, learner, hosts


def _starting_learner(run: _Run, algorithm: Algorithm, hosts: Hosts, humans: Humans,
                      hooks: TrialHooks) -> tuple[Hosts, Any]:
    """The expert (hosts wrapped), the resumed learner, a given policy, or theta_0."""
    opts, state = run.opts, run.state
    if opts.expert:  # the expert row: the twin's expert acts, nothing is learned
        from testbed.experiments.expert import ExpertHosts, ExpertPolicy

        expert_hosts = ExpertHosts(hosts)
        if state is not None:
            algorithm.load_state_dict(state["algorithm"])
        return expert_hosts, ExpertPolicy(expert_hosts)
    if state is not None:
        learner = resume_learner(run.cfg, run.dir, state, learns=algorithm.learns)
        algorithm.load_state_dict(state["algorithm"])
        return hosts, learner
    if opts.policy is not None:
        return hosts, load_learner(run.cfg, Path(opts.policy))
    critics = algorithm.spec.critics | set(opts.pretrain_critics or ())
    learner, theta_0 = pretrained_learner(
        run.cfg, humans, Path(opts.out), hooks, hosts=hosts, trial_seed=opts.seed,
        critics=critics, pretrain_seed=(PRETRAIN_SEED if opts.pretrain_seed is None
                                        else opts.pretrain_seed))
    keep_demos(theta_0.parent / "demos.npz", run.dir)
    return hosts, learner


def _run_steps(run: _Run, hosts: Hosts, humans: Humans, learner: Any, algorithm: Algorithm,
               hooks: TrialHooks) -> int | None:
    """The loop from the run's start to its last step; the step the operator stopped
    at (Esc), or None when every step ran (the trained policy saved)."""
    opts, cfg = run.opts, run.cfg
    if run.state is None:  # the trial seed, not theta_0's, drives sampling from here on
        learner.reseed(opts.seed)
        if not opts.expert:  # what resume replays the run's data onto
            with critical():
                learner.save(run.dir.start_learner)
    loop: FleetLoop | None = None
    checkpoints: CheckpointWriter | None = None
    writer: RunWriter | None = None
    data: RunDataWriter | None = None
    stopped_at: int | None = None
    try:
        data = _data_writer(run)
        writer = RunWriter(run.dir.path)
        checkpoints = CheckpointWriter(run.dir.path)
        ckpt = checkpoints

        def checkpoint(step: int) -> None:
            ckpt.submit(step, learner, {"algorithm": algorithm.state_dict()})

        loop = FleetLoop(hosts=hosts, humans=humans, learner=learner, algorithm=algorithm,
                         writer=writer, steps=opts.steps, num_humans=cfg.humans.count,
                         t_T=cfg.algorithm.t_T, t_R=cfg.algorithm.t_R,
                         after_step=checkpoint, data=data,
                         session=len(run.meta.get("resumed", [])), cells=shared_cells(cfg))
        loop.restore_counters(run.prior_rows)
        if run.start and data is not None:  # the open episodes, for learning by class
            loop.restore_feed(frames for _, frames in
                              RunData.of_run(run.dir.path).iter_steps(0, run.start))
        stopped_at = _steps(loop, run.start, opts.steps, hooks)
        checkpoints.wait()
        run.meta["checkpoint"] = checkpoints.stats()
        if stopped_at is not None and stopped_at >= opts.steps:
            stopped_at = None  # the stop came after the last step: nothing is left
        if stopped_at is None:
            with critical():
                learner.save(run.dir.learner)  # the trained policy: testbed evaluate --policy
    finally:
        if checkpoints is not None:
            with contextlib.suppress(RuntimeError):
                checkpoints.wait()
        if loop is not None:
            loop.close()
        if writer is not None:
            writer.close()
        if data is not None:
            data.close()
    return stopped_at


def _steps(loop: FleetLoop, start: int, steps: int, hooks: TrialHooks) -> int | None:
    """Steps ``start`` .. ``steps - 1``; the step to resume from if the operator stopped."""
    for t in range(start, steps):
        try:
            outcome = loop.step(t)
        except HumansStopRequested as stop:  # Esc + confirm on the console
            # From act: step t did not happen; from show: it did (logged and
            # checkpointed), and status.t is already t + 1. Resume starts there.
            stopped_at = max(t, loop.status.t)
            LOG.warning("trial stopped by the operator at step %d: %s", stopped_at, stop)
            return stopped_at
        hooks.on_step(outcome)
    return None


def _data_writer(run: _Run) -> RunDataWriter | None:
    """The run's data store, appended from the run's start (None: a run from before
    the data store, resumed without one)."""
    if run.state is None or (run.dir.path / DATA_FOLDER / DATA_META).exists():
        return RunDataWriter(run.dir.path, run.cfg.robot_names, keep_steps=run.start)
    LOG.warning("%s has no data/ (an older run): resumed without a data store", run.dir.path)
    return None


def _finish(run: _Run, stopped_at: int | None) -> tuple[RunDir, dict[str, Any]]:
    """run.json's last word and the summary: complete (summary.json written) or stopped."""
    label = run.opts.label or run.opts.algorithm
    num_humans, num_robots = run.cfg.humans.count, len(run.cfg.robot_names)
    if stopped_at is not None:
        run.save_meta(status=STOPPED, stopped_at=stopped_at, stopped_time=time.time())
        steps = read_steps(run.dir.steps) if run.dir.steps.exists() else []
        summary = summarize(steps, algorithm=label, num_humans=num_humans,
                            num_robots=num_robots)
        return run.dir, {**summary, "status": STOPPED, "stopped_at": stopped_at}
    summary = write_summary(run.dir, label, num_humans, num_robots)
    run.save_meta(status=COMPLETE, finished=time.time())
    return run.dir, {**summary, "status": COMPLETE}


def _with_hosts(cfg: FleetConfig, hosts: Sequence[HostConfig], where: Path) -> FleetConfig:
    """``cfg`` driving ``hosts`` instead; the robots must be the run's own."""
    new = cfg.model_copy(update={"hosts": list(hosts)})
    if new.robot_names != cfg.robot_names:
        raise ConfigError(
            f"{where}: the fleet's robots {new.robot_names} are not the run's "
            f"{cfg.robot_names}; resume with the fleet the run was started with"
        )
    return new


def _rewrite_steps(path: Path, rows: list[dict[str, Any]]) -> None:
    """Drop the steps past the checkpoint (logged, but their checkpoint never landed)."""
    text = "".join(json.dumps(r, separators=(",", ":")) + "\n" for r in rows)
    atomic_write_bytes(path, text.encode())


def write_summary(run: RunDir, algorithm: str, num_humans: int, num_robots: int) -> dict[str, Any]:
    steps = read_steps(run.steps)
    summary = summarize(steps, algorithm=algorithm, num_humans=num_humans, num_robots=num_robots)
    atomic_write_json(run.summary, summary)
    return summary
