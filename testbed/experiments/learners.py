"""The learner a run starts from: new, loaded, resumed, or theta_0 (pretrained, cached).

Why apart from the trial: every entry point needs one of these (a trial, ``testbed
pretrain``, ``testbed train``, the Ray fan-out's pretraining task, the benchmarks), and
theta_0 has rules of its own: one per fleet (every algorithm and trial of a protocol
starts from it: a fair comparison), cached under a key of everything that shaped it,
and the same whichever trial happened to make it. torch is imported only when a learner
is made.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from testbed.core.hosts import Hosts
from testbed.core.humans import Humans
from testbed.experiments.fleet_config import FleetConfig
from testbed.experiments.hooks import TrialHooks
from testbed.experiments.pretraining import Progress, critic_set
from testbed.experiments.theta0 import (
    PRETRAIN_HOSTS_SEED,
    PRETRAIN_SEED,
    make_theta0,
    own_hosts,
    pretrain_hosts_seed,
    theta0_folder,
)
from testbed.records.run_dir import RunDir

__all__ = ["PRETRAIN_HOSTS_SEED", "PRETRAIN_SEED", "keep_demos", "load_learner",
           "new_learner", "pretrained_learner", "resume_learner"]

def new_learner(cfg: FleetConfig, seed: int) -> Any:
    from testbed.learning import Learner

    return Learner(cfg.learning, seed=seed)


def load_learner(cfg: FleetConfig, path: Path) -> Any:
    from testbed.learning import Learner

    return Learner.load(path, cfg.learning)


def name_fleet(learner: Any, cfg: FleetConfig) -> None:
    """Tell a learner who the run's humans are (``Learner.name_fleet``: the loop gives
    labels by human index, and the learner keeps them by name); a learner without the
    call (the expert's, a test's) is left as it is."""
    tell = getattr(learner, "name_fleet", None)
    if callable(tell):
        tell(cfg.humans.names)


def resume_learner(cfg: FleetConfig, run: RunDir, state: Mapping[str, Any], *,
                   learns: bool = True) -> Any:
    """The learner as it was after step ``state["t"]`` of ``run``: the run's starting
    learner (theta_0 and its data, reseeded), the run's data replayed onto it as the
    loop gave it (``testbed.records.store.replay``; nothing for an algorithm that does
    not learn), then the step's weights, optimisers, sampler and counters. A checkpoint
    of the old format (the whole learner, data included) is loaded as it is."""
    from testbed.learning import checkpoint as ckpt_format
    from testbed.records.store import RunData, replay

    path = run.path / state["learner"]
    saved = ckpt_format.load_any(path)
    if saved["format"] == ckpt_format.FORMAT:
        return load_learner(cfg, path)
    learner = load_learner(cfg, run.start_learner)
    name_fleet(learner, cfg)  # before the replay: its labels by name, as the loop's were
    if learns:
        replay(learner, RunData.of_run(run.path), int(state["t"]) + 1)
    learner.load_training_state(saved, where=str(path))
    return learner


def pretrained_learner(
    cfg: FleetConfig,
    humans: Humans,
    out: Path,
    progress: Progress | TrialHooks | None,
    hosts: Hosts | None = None,
    trial_seed: int | None = None,
    critics: Iterable[str] | None = None,
    pretrain_seed: int = PRETRAIN_SEED,
) -> tuple[Any, Path]:
    """theta_0: from the cache if this exact pretraining was done before, else made now.

    ``critics``: the critics to pretrain (None: both), part of the cache key. The
    learner comes back with every part set to train; the caller narrows it
    (``Learner.set_parts``) to what its algorithm reads. ``progress``: a trial's hooks
    (``on_phase``, and ``on_phase_resumed`` for a phase that goes on from what an
    earlier try kept) or a bare progress callable.

    A cold cache pretrains on the trial's own ``hosts`` (already started): one agent
    per host, ever, which on hardware means one lock, one camera client, one SSH
    session. They are reseeded to ``PRETRAIN_HOSTS_SEED`` first (theta_0 does not
    depend on which trial happened to pretrain) and to ``trial_seed`` after, which
    puts every host where a fresh start with that seed would; and the learner is
    always reloaded from the checkpoint: so a trial is reproducible, cold cache or
    warm. Without ``hosts`` (``testbed pretrain``-like callers, benchmarks) pretraining
    builds and closes hosts of its own. Each phase keeps what it made in the cache as
    it goes, and a cache that holds part of it goes on from there
    (``testbed.experiments.theta0``).

    ``pretrain_seed``: the seed theta_0 is pretrained from (``PRETRAIN_SEED``: the one
    every trial shares; a protocol with ``pretrain_per_trial`` gives the trial's seed,
    and each seed's theta_0 is cached apart, its hosts' world at
    ``pretrain_hosts_seed(pretrain_seed)``).
    """
    which = critic_set(critics)
    ckpt = theta0_folder(out, cfg, which, pretrain_seed) / "learner.pt"
    if not ckpt.exists():
        if hosts is None:
            with own_hosts(cfg, pretrain_seed) as own:
                make_theta0(cfg, humans, out, which, own, progress, seed=pretrain_seed)
        else:
            if trial_seed is None:
                raise ValueError("pretraining on the trial's hosts needs the trial seed")
            hosts.reseed(pretrain_hosts_seed(pretrain_seed))
            make_theta0(cfg, humans, out, which, hosts, progress, seed=pretrain_seed)
            hosts.reseed(trial_seed)
    return load_learner(cfg, ckpt), ckpt


def keep_demos(demos: Path, run: RunDir) -> None:
    """The offline demonstrations theta_0 learned from, beside the run's data
    (``data/demos.npz``, ``testbed.experiments.pretraining.save_transitions``' format:
    a hard link to the pretraining cache's file where the file system allows), so that
    the run's folder alone holds every label its policy saw (``testbed export``)."""
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
