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
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from testbed.checkpoints import CheckpointWriter
from testbed.config import ConfigError, FleetConfig
from testbed.fleet import FleetLoop, StepOutcome
from testbed.humans import Humans, HumansStopRequested, make_humans
from testbed.interrupts import critical
from testbed.offline import (
    Progress,
    collect_demos,
    load_transitions,
    pretrain,
    pretrain_key,
    save_transitions,
)
from testbed.priorities import get_algorithm
from testbed.records import (
    RunWriter,
    atomic_write_json,
    read_steps,
    summarize,
    truncate_torn_tail,
)
from testbed.runs import RunDir, new_run_dir

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


def build_hosts(cfg: FleetConfig, seed: int) -> Any:
    from drivers.fleet import HostFleet

    return HostFleet(cfg.hosts, trial_seed=seed)


def new_learner(cfg: FleetConfig, seed: int) -> Any:
    from testbed.learning import Learner

    return Learner(cfg.learning, seed=seed)


def load_learner(cfg: FleetConfig, path: Path) -> Any:
    from testbed.learning import Learner

    return Learner.load(path, cfg.learning)


PRETRAIN_SEED = 0
"""Every algorithm and trial of a fleet starts from the same theta_0 (a fair comparison)."""


def pretrained_learner(
    cfg: FleetConfig, humans: Humans, out: Path, progress: Progress | None
) -> tuple[Any, Path]:
    """theta_0: from the cache if this exact pretraining was done before, else made now.

    Pretraining drives hosts of its own (seeded by ``PRETRAIN_SEED``), so the trial's
    hosts start from the same state whether the cache was warm or cold, and the learner
    is always reloaded from the checkpoint: a trial is reproducible either way.
    """
    cache = out / ".pretrained" / pretrain_key(cfg, PRETRAIN_SEED)
    ckpt = cache / "learner.pt"
    if not ckpt.exists():
        cache.mkdir(parents=True, exist_ok=True)
        hosts = build_hosts(cfg, PRETRAIN_SEED + 104729)
        try:
            hosts.start()
            demos_path = cache / "demos.npz"
            if demos_path.exists():
                demos = load_transitions(demos_path)
            else:
                demos = collect_demos(
                    hosts, humans, cfg.learning.demos, cfg.algorithm.t_R, progress
                )
                save_transitions(demos, demos_path)
            learner = new_learner(cfg, PRETRAIN_SEED)
            data = pretrain(
                learner, cfg.learning, demos, hosts, humans, cfg.algorithm.t_R,
                PRETRAIN_SEED, progress,
            )
            save_transitions(data, cache / "transitions.npz")
            learner.save(ckpt)
        finally:
            try:
                hosts.rest()
            finally:
                hosts.close()
    return load_learner(cfg, ckpt), ckpt


def run_trial(
    cfg: FleetConfig,
    opts: TrialOptions,
    *,
    resume: Path | None = None,
    on_step: Callable[[StepOutcome], None] | None = None,
    progress: Progress | None = None,
    hosts: Any = None,
) -> tuple[RunDir, dict[str, Any]]:
    """Run (or resume) a trial; return its folder and its summary."""
    num_robots = len(cfg.robot_names)
    start = 0
    prior_rows: list[dict[str, Any]] = []
    if resume is not None:
        run = RunDir(resume)
        cfg = run.read_config()
        meta = run.read_meta()
        opts = TrialOptions(**meta["options"])
        if not run.state.exists():
            raise ConfigError(f"{resume}: no checkpoint yet (state.json); start a new trial")
        state = json.loads(run.state.read_text())
        truncate_torn_tail(run.steps)
        prior_rows = [r for r in read_steps(run.steps) if r["t"] <= state["t"]]
        _rewrite_steps(run.steps, prior_rows)
        start = state["t"] + 1
    else:
        run = new_run_dir(opts.out, opts.name or f"{opts.algorithm}-s{opts.seed}")
        run.write_config(cfg)
        run.write_meta({"options": opts.__dict__, "created": time.time()})
        state = None

    algorithm = get_algorithm(
        opts.algorithm, cfg.algorithm, num_robots, cfg.humans.count, opts.seed
    )
    humans = make_humans(opts.humans, cfg.humans.count)
    own_hosts = hosts is None
    if own_hosts:
        hosts = build_hosts(cfg, opts.seed + (start * 7919 if start else 0))
    loop: FleetLoop | None = None
    checkpoints: CheckpointWriter | None = None
    writer: RunWriter | None = None
    try:
        if own_hosts:
            hosts.start()
        if state is not None:
            learner = load_learner(cfg, run.path / state["learner"])
            algorithm.load_state_dict(state["algorithm"])
        elif opts.policy is not None:
            learner = load_learner(cfg, Path(opts.policy))
        else:
            learner, _ = pretrained_learner(cfg, humans, Path(opts.out), progress)
        if state is None:  # the trial seed, not theta_0's, drives sampling from here on
            learner.reseed(opts.seed)
        writer = RunWriter(run.path)

        checkpoints = CheckpointWriter(run.path)

        def checkpoint(t: int) -> None:
            checkpoints.submit(t, learner, {"algorithm": algorithm.state_dict()})

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
        )
        loop.restore_counters(prior_rows)
        for t in range(start, opts.steps):
            try:
                outcome = loop.step(t)
            except HumansStopRequested as stop:  # Esc + confirm on the console
                LOG.warning("trial stopped by the operator at step %d: %s", t, stop)
                break
            if on_step is not None:
                on_step(outcome)
        checkpoints.wait()
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
        if own_hosts:
            try:
                hosts.rest()
            finally:
                hosts.close()
        humans.close()
    summary = write_summary(run, opts.algorithm, cfg.humans.count, num_robots)
    return run, summary


def _rewrite_steps(path: Path, rows: list[dict[str, Any]]) -> None:
    """Drop the steps past the checkpoint (logged, but their checkpoint never landed)."""
    from testbed.records import atomic_write_bytes

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
