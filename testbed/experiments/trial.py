"""One trial end to end: setup, pretraining (cached), the loop, records, teardown.

This is the thin script around ``FleetLoop`` (as LeRobot's record script around its
robot): it builds the hosts, humans and learner from the config, runs the steps
inside ``try/finally`` so that, whatever happens, the arms go to their rest pose and
the records are closed, and it checkpoints every complete step so that
``--resume`` continues where a crash or a kill left off.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from testbed.core.atomic import atomic_write_json
from testbed.core.config import AlgorithmConfig, ConfigError, FleetConfig, HostConfig
from testbed.core.humans import Humans, HumansStopRequested
from testbed.core.interrupts import critical
from testbed.experiments.build import make_humans
from testbed.experiments.checkpointer import CheckpointWriter
from testbed.experiments.pretraining import (
    Progress,
    collect_demos,
    critic_set,
    load_transitions,
    pretrain,
    pretrain_key,
    save_transitions,
)
from testbed.fleet.loop import FleetLoop, StepOutcome
from testbed.fleet.priorities import get_algorithm
from testbed.fleet.thresholds import SIGNAL, resolve_thresholds
from testbed.records.metrics import summarize
from testbed.records.run_dir import RunDir, new_run_dir
from testbed.records.steps import RunWriter, read_steps, truncate_torn_tail
from testbed.records.store import FOLDER as DATA_FOLDER
from testbed.records.store import META as DATA_META
from testbed.records.store import RunDataWriter

LOG = logging.getLogger(__name__)


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


def build_hosts(cfg: FleetConfig, seed: int, log_dir: Path | None = None) -> Any:
    """The fleet's ``HostFleet``; with ``log_dir`` each host's agent log and the
    controller's events about it go to ``log_dir/<host>.log`` (DESIGN.md section 9)."""
    from drivers.host_fleet import HostFleet

    if log_dir is None:
        return HostFleet(cfg.hosts, trial_seed=seed)
    return HostFleet(cfg.hosts, trial_seed=seed, log_dir=log_dir)


def new_learner(cfg: FleetConfig, seed: int) -> Any:
    from testbed.learning import Learner

    return Learner(cfg.learning, seed=seed)


def load_learner(cfg: FleetConfig, path: Path) -> Any:
    from testbed.learning import Learner

    return Learner.load(path, cfg.learning)


def resume_learner(cfg: FleetConfig, run: RunDir, state: Mapping[str, Any], *,
                   learns: bool = True) -> Any:
    """The learner as it was after step ``state["t"]`` of ``run``: the run's starting
    learner (theta_0 and its data, reseeded), the run's data replayed onto it as the
    loop gave it (``testbed.records.store.replay``; nothing for an algorithm that does not
    learn), then the step's weights, optimisers, sampler and counters. A checkpoint of
    the old format (the whole learner, data included) is loaded as it is."""
    from testbed.learning import checkpoint as ckpt_format
    from testbed.records.store import RunData, replay

    path = run.path / state["learner"]
    saved = ckpt_format.load_any(path)
    if saved["format"] == ckpt_format.FORMAT:
        return load_learner(cfg, path)
    learner = load_learner(cfg, run.start_learner)
    if learns:
        replay(learner, RunData.of_run(run.path), int(state["t"]) + 1)
    learner.load_training_state(saved, where=str(path))
    return learner


PRETRAIN_SEED = 0
"""Every algorithm and trial of a fleet starts from the same theta_0 (a fair comparison)."""

PRETRAIN_HOSTS_SEED = PRETRAIN_SEED + 104729
"""The hosts' trial seed while pretraining: the same world whichever trial pretrains."""


def pretrained_learner(
    cfg: FleetConfig,
    humans: Humans,
    out: Path,
    progress: Progress | None,
    hosts: Any = None,
    trial_seed: int | None = None,
    critics: Iterable[str] | None = None,
) -> tuple[Any, Path]:
    """theta_0: from the cache if this exact pretraining was done before, else made now.

    ``critics``: the critics to pretrain (None: both), part of the cache key. The
    learner comes back with every part set to train; the caller narrows it
    (``Learner.set_parts``) to what its algorithm reads.

    A cold cache pretrains on the trial's own ``hosts`` (already started): one agent
    per host, ever, which on hardware means one lock, one camera client, one SSH
    session. They are reseeded to ``PRETRAIN_HOSTS_SEED`` first (theta_0 does not
    depend on which trial happened to pretrain) and to ``trial_seed`` after, which
    puts every host where a fresh start with that seed would; and the learner is
    always reloaded from the checkpoint: so a trial is reproducible, cold cache or
    warm. Without ``hosts`` (``testbed pretrain``-like callers, benchmarks) pretraining
    builds and closes hosts of its own.
    """
    which = critic_set(critics)
    cache = out / ".pretrained" / pretrain_key(cfg, PRETRAIN_SEED, which)
    ckpt = cache / "learner.pt"
    if not ckpt.exists():
        cache.mkdir(parents=True, exist_ok=True)
        if hosts is None:
            own = build_hosts(cfg, PRETRAIN_HOSTS_SEED)
            try:
                own.start()
                _pretrain_into(cfg, humans, cache, own, progress, which)
            finally:
                try:
                    own.rest()
                finally:
                    own.close()
        else:
            if trial_seed is None:
                raise ValueError("pretraining on the trial's hosts needs the trial seed")
            hosts.reseed(PRETRAIN_HOSTS_SEED)
            _pretrain_into(cfg, humans, cache, hosts, progress, which)
            hosts.reseed(trial_seed)
    return load_learner(cfg, ckpt), ckpt


def _pretrain_into(
    cfg: FleetConfig, humans: Humans, cache: Path, hosts: Any, progress: Progress | None,
    critics: tuple[str, ...],
) -> None:
    """Collect the demos (unless cached), pretrain theta_0, write it to ``cache``."""
    demos_path = cache / "demos.npz"
    if demos_path.exists():
        demos = load_transitions(demos_path)
    else:
        demos = collect_demos(hosts, humans, cfg.learning.demos, cfg.algorithm.t_R, progress)
        save_transitions(demos, demos_path)
    learner = new_learner(cfg, PRETRAIN_SEED)
    data = pretrain(learner, cfg.learning, demos, hosts, humans, cfg.algorithm.t_R,
                    PRETRAIN_SEED, progress, critics=critics)
    save_transitions(data, cache / "transitions.npz")
    learner.save(cache / "learner.pt")


COMPLETE = "complete"
STOPPED = "stopped"
RUNNING = "running"
"""run.json ``status``: ``running`` until the loop ends (also what a crash or a kill
leaves), ``stopped`` when the operator stopped it (Esc; resumable, no summary),
``complete`` when every step ran (summary.json written)."""


def run_trial(
    cfg: FleetConfig,
    opts: TrialOptions,
    *,
    resume: Path | None = None,
    on_step: Callable[[StepOutcome], None] | None = None,
    progress: Progress | None = None,
    hosts: Any = None,
    humans: Humans | None = None,
    meta: Mapping[str, Any] | None = None,
    host_configs: Sequence[HostConfig] | None = None,
    wrap_hosts: Callable[[Any, RunDir], Any] | None = None,
) -> tuple[RunDir, dict[str, Any]]:
    """Run (or resume) a trial; return its folder and its summary.

    ``humans``: who answers the interventions (default: ``make_humans`` of
    ``opts.humans`` and the config's ``humans``, ``[humans.web]`` included); the trial
    closes it. ``meta``: extra keys for a new run's run.json (a protocol's
    trial index and algorithm order). ``host_configs``: drive these hosts instead of
    the run's (same host and arm names): a resumed protocol run takes the protocol's
    current fleet, e.g. the fresh ports of a rehearsal or a lab's edited addresses.
    ``wrap_hosts(hosts, run)``: wraps the hosts the trial builds (a rehearsal's truth
    recorder); the wrapper passes start/rest/close/reseed through.

    The summary has ``status``: ``complete`` (summary.json written) or ``stopped``
    (the operator pressed Esc: run.json says ``stopped`` and the step; resume it with
    ``testbed trial --resume`` or by rerunning the protocol; no summary.json until
    it is finished).
    """
    num_robots = len(cfg.robot_names)
    start = 0
    prior_rows: list[dict[str, Any]] = []
    if resume is not None:
        run = RunDir(resume)
        cfg = run.read_config()
        written = cfg
        run_meta = run.read_meta()
        opts = TrialOptions(**run_meta["options"])
        if not run.state.exists():
            raise ConfigError(f"{resume}: no checkpoint yet (state.json); start a new trial")
        state = json.loads(run.state.read_text())
        truncate_torn_tail(run.steps)
        prior_rows = [r for r in read_steps(run.steps) if r["t"] <= state["t"]]
        _rewrite_steps(run.steps, prior_rows)
        start = state["t"] + 1
        run_meta.update(status=RUNNING, resumed=[*run_meta.get("resumed", []), time.time()])
        run_meta.pop("stopped_at", None)
        run.write_meta(run_meta)
    else:
        run = new_run_dir(opts.out, opts.name or f"{opts.algorithm}-s{opts.seed}")
        run.write_config(cfg)
        written = cfg  # config.toml: the fleet as given (not host_configs' rewrite)
        run_meta = {**(meta or {}), "options": opts.__dict__, "created": time.time(),
                    "status": RUNNING}
        run.write_meta(run_meta)
        state = None
    if host_configs is not None:
        cfg = _with_hosts(cfg, host_configs, run.path)
    num_robots = len(cfg.robot_names)

    # Thresholds given as quantiles are resolved on theta_0 below, those the algorithm
    # reads (BC reads neither): until then it is built with placeholders (its spec is
    # all that pretraining needs). Unread ones stay as given in config.toml.
    algorithm = get_algorithm(opts.algorithm, _placeholders(cfg.algorithm), num_robots,
                              cfg.humans.count, opts.seed)
    pending = {k: q for k, q in cfg.algorithm.quantile_thresholds.items()
               if SIGNAL[k] in algorithm.spec.reads}
    if humans is None:
        humans = make_humans(opts.humans, cfg.humans.count, cfg.humans.web)
    own_hosts = hosts is None
    if own_hosts:
        hosts = build_hosts(cfg, opts.seed + (start * 7919 if start else 0),
                            log_dir=run.path / "hosts")
        if wrap_hosts is not None:
            hosts = wrap_hosts(hosts, run)
    loop: FleetLoop | None = None
    checkpoints: CheckpointWriter | None = None
    writer: RunWriter | None = None
    data: RunDataWriter | None = None
    stopped_at: int | None = None
    try:
        if own_hosts:
            hosts.start()
        try:
            if opts.expert:  # the expert row: the twin's expert acts, nothing is learned
                from testbed.experiments.expert import ExpertHosts, ExpertPolicy

                hosts = ExpertHosts(hosts)
                learner = ExpertPolicy(hosts)
                if state is not None:
                    algorithm.load_state_dict(state["algorithm"])
            elif state is not None:
                learner = resume_learner(cfg, run, state, learns=algorithm.learns)
                algorithm.load_state_dict(state["algorithm"])
            elif opts.policy is not None:
                learner = load_learner(cfg, Path(opts.policy))
            else:
                critics = algorithm.spec.critics | set(opts.pretrain_critics or ())
                learner, theta_0 = pretrained_learner(cfg, humans, Path(opts.out), progress,
                                                      hosts=hosts, trial_seed=opts.seed,
                                                      critics=critics)
                keep_demos(theta_0.parent / "demos.npz", run)
            if pending:  # a new run (a resumed one reads the resolved config back)
                cfg, resolved = resolve_thresholds(cfg, learner, only=pending)
                run.write_config(written.model_copy(update={"algorithm": cfg.algorithm}))
                run_meta["thresholds"] = resolved
                run.write_meta(run_meta)
                algorithm = get_algorithm(opts.algorithm, _placeholders(cfg.algorithm),
                                          num_robots, cfg.humans.count, opts.seed)
            # whatever theta_0 had trained: from here on only what this algorithm reads
            learner.set_parts(train=algorithm.spec.train_parts, read=algorithm.spec.critics)
            if callable(getattr(learner, "numerics", None)):  # threads etc., for the lab
                run_meta["numerics"] = learner.numerics()
                run.write_meta(run_meta)
        except HumansStopRequested as stop:  # Esc while the demos were being collected
            LOG.warning("trial stopped by the operator before step %d: %s", start, stop)
            stopped_at = start
        if stopped_at is None:
            if state is None:  # the trial seed, not theta_0's, drives sampling from here on
                learner.reseed(opts.seed)
                if not opts.expert:  # what resume replays the run's data onto
                    with critical():
                        learner.save(run.start_learner)
            if state is None or (run.path / DATA_FOLDER / DATA_META).exists():
                data = RunDataWriter(run.path, cfg.robot_names, keep_steps=start)
            else:  # a run from before the data store: it goes on without one
                LOG.warning("%s has no data/ (an older run): resumed without a data store",
                            run.path)
            writer = RunWriter(run.path)

            checkpoints = CheckpointWriter(run.path)

            def checkpoint(step: int) -> None:
                checkpoints.submit(step, learner, {"algorithm": algorithm.state_dict()})

            loop = FleetLoop(
                hosts=hosts,
                humans=humans,
                learner=learner,
                algorithm=algorithm,
                writer=writer,
                steps=opts.steps,
                num_humans=cfg.humans.count,
                t_T=cfg.algorithm.t_T,
                t_R=cfg.algorithm.t_R,
                after_step=checkpoint,
                data=data,
                session=len(run_meta.get("resumed", [])),
            )
            loop.restore_counters(prior_rows)
            for t in range(start, opts.steps):
                try:
                    outcome = loop.step(t)
                except HumansStopRequested as stop:  # Esc + confirm on the console
                    # From act: step t did not happen; from show: it did (logged and
                    # checkpointed), and status.t is already t + 1. Resume starts there.
                    stopped_at = max(t, loop.status.t)
                    LOG.warning("trial stopped by the operator at step %d: %s", stopped_at,
                                stop)
                    break
                if on_step is not None:
                    on_step(outcome)
            checkpoints.wait()
            run_meta["checkpoint"] = checkpoints.stats()
            if stopped_at is not None and stopped_at >= opts.steps:
                stopped_at = None  # the stop came after the last step: nothing is left
            if stopped_at is None:
                with critical():
                    learner.save(run.learner)  # the trained policy: testbed evaluate --policy
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
        if own_hosts:
            try:
                hosts.rest()
            finally:
                hosts.close()
        humans.close()
    if stopped_at is not None:
        run_meta.update(status=STOPPED, stopped_at=stopped_at, stopped_time=time.time())
        run.write_meta(run_meta)
        summary = summarize(read_steps(run.steps) if run.steps.exists() else [],
                            algorithm=opts.label or opts.algorithm,
                            num_humans=cfg.humans.count, num_robots=num_robots)
        return run, {**summary, "status": STOPPED, "stopped_at": stopped_at}
    summary = write_summary(run, opts.label or opts.algorithm, cfg.humans.count, num_robots)
    run_meta.update(status=COMPLETE, finished=time.time())
    run.write_meta(run_meta)
    return run, {**summary, "status": COMPLETE}


def keep_demos(demos: Path, run: RunDir) -> None:
    """The offline demonstrations theta_0 learned from, beside the run's data
    (``data/demos.npz``, ``testbed.experiments.pretraining.save_transitions``' format:
    a hard link to the pretraining cache's file where the file system allows), so that
    the run's folder
    alone holds every label its policy saw (``testbed export``)."""
    if not demos.exists():
        return
    target = run.path / "data" / "demos.npz"
    target.parent.mkdir(parents=True, exist_ok=True)
    if target.exists():
        return
    try:
        os.link(demos, target)
    except OSError:
        shutil.copyfile(demos, target)


def _placeholders(params: AlgorithmConfig) -> AlgorithmConfig:
    """``params`` with every threshold still given as a quantile set to 0.0: one the
    algorithm does not read, or one not resolved yet (the algorithm is rebuilt then)."""
    return params.model_copy(update=dict.fromkeys(params.quantile_thresholds, 0.0))


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
    from testbed.core.atomic import atomic_write_bytes

    text = "".join(json.dumps(r, separators=(",", ":")) + "\n" for r in rows)
    atomic_write_bytes(path, text.encode())


def write_summary(run: RunDir, algorithm: str, num_humans: int, num_robots: int) -> dict[str, Any]:
    steps = read_steps(run.steps)
    summary = summarize(steps, algorithm=algorithm, num_humans=num_humans, num_robots=num_robots)
    atomic_write_json(run.summary, summary)
    return summary


def mosaic(images: list[np.ndarray], cols: int = 4, scale: int = 4) -> np.ndarray:
    """Tile arm images (upscaled) into one picture for ``testbed check``."""
    if not images:
        return np.zeros((64 * scale, 64 * scale, 3), np.uint8)
    rows = (len(images) + cols - 1) // cols
    h, w = images[0].shape[0] * scale, images[0].shape[1] * scale
    out = np.zeros((rows * h, min(cols, len(images)) * w, 3), np.uint8)
    for k, img in enumerate(images):
        big = np.kron(img, np.ones((scale, scale, 1), np.uint8))
        r, c = divmod(k, cols)
        out[r * h : (r + 1) * h, c * w : (c + 1) * w] = big
    return out
