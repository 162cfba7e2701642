"""theta_0's cache: where each phase of pretraining keeps what it made, what is there
already, and the resumable pretraining that fills it.

Why apart from ``learners.py``: before step 1 a physical trial collects hundreds of
teleoperated demonstrations and a thousand policy pushes (over an hour of arm time,
issue 44). A crash, a Ctrl-C or the operator's Esc must not throw that away, and
``testbed collect`` / ``testbed pretrain`` must fill the very cache the trial reads, so
the phases are run ahead as named steps. Layout under a folder of runs::

    <out>/.pretrained/
      demos/<demos_key>.npz   the demonstrations of these arms, grown as they come
                              (rewritten atomically every KEEP_EVERY_S and whenever the
                              collection stops early); shared by every theta_0 of the
                              arms, whatever its critics or learning sizes
      <pretrain_key>/         one theta_0 (``pretraining.pretrain_key``):
        policy.pt             the policy after its phase      } removed once
        rollouts.npz          the BC rollouts so far          } learner.pt is written
        demos.npz             the demonstrations it learnt from (its runs link it)
        transitions.npz       what its critics learnt from
        learner.pt            theta_0

A cache made before this layout is found as it was: ``<pretrain_key>/learner.pt``, or
``<pretrain_key>/demos.npz`` alone (a pretraining that died after its collection).

A resumed collection is not bit-identical to an uninterrupted one: the hosts start again
from the pretraining seed's world, not from where the arms and cubes were when it
stopped, so the pairs after the resume differ (the ones kept are kept as they were). A
resumed rollout likewise, and its noise comes from another stream. An uninterrupted
pretraining is exactly what it was before the cache kept its phases.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, NamedTuple

import numpy as np

from testbed.core.hosts import Hosts
from testbed.core.humans import Humans
from testbed.experiments.fleet_config import FleetConfig
from testbed.experiments.hooks import TrialHooks
from testbed.experiments.pretraining import (
    Progress,
    Resume,
    collect_demos,
    concat,
    critic_set,
    demos_key,
    head,
    load_transitions,
    pretrain,
    pretrain_key,
    save_transitions,
)

if TYPE_CHECKING:
    from testbed.learning.api import Transitions

__all__ = ["CACHE", "KEEP_EVERY_S", "PRETRAIN_HOSTS_SEED", "PRETRAIN_SEED", "CacheState",
           "PartialFile", "Report", "Theta0Spec", "as_report", "cache_state", "collect_into",
           "demos_file", "make_theta0", "npz_length", "own_hosts", "pretrain_hosts_seed",
           "theta0_folder"]

PRETRAIN_SEED: Final = 0
"""Every algorithm and trial of a fleet starts from the same theta_0 (a fair comparison),
pretrained from this seed; a protocol with ``pretrain_per_trial`` pretrains each trial's
from the trial's seed instead (issue 45, item 1: a held-out theta_0 that is one)."""

PRETRAIN_HOSTS_SEED: Final = PRETRAIN_SEED + 104729
"""The hosts' trial seed while pretraining: the same world whichever trial pretrains."""


def pretrain_hosts_seed(seed: int) -> int:
    """The hosts' seed while pretraining theta_0 from ``seed``: ``PRETRAIN_HOSTS_SEED``
    for the shared theta_0 (as before), shifted by the seed for a trial's own, so each
    trial's demonstrations come from a world of its own."""
    return PRETRAIN_HOSTS_SEED + seed - PRETRAIN_SEED


class Theta0Spec(NamedTuple):
    """One theta_0 to have before step 1, as the plan and ``testbed collect``/``pretrain``
    name it: its fleet, its critics, which of several it is ("" for one alone: "for cur,
    monitor", "trial 2") and the seed it is pretrained from (a protocol with
    ``pretrain_per_trial`` has one per trial, each its trial's seed)."""

    cfg: FleetConfig
    critics: tuple[str, ...]
    label: str = ""
    seed: int = PRETRAIN_SEED


CACHE: Final = ".pretrained"
KEEP_EVERY_S: Final = 5.0
"""A collection's partial file is rewritten at most this often (and when it stops early):
a crash loses at most these seconds of pushes; on the twin, where 375 pairs take a
second, it is written once or twice."""


def theta0_folder(out: Path, cfg: FleetConfig, critics: Iterable[str] | None,
                  seed: int = PRETRAIN_SEED) -> Path:
    """The folder of the theta_0 of ``cfg`` with ``critics`` (None: both) pretrained from
    ``seed`` under ``out`` (one per seed: the seed is part of its key)."""
    return out / CACHE / pretrain_key(cfg, seed, critic_set(critics))


def demos_file(out: Path, cfg: FleetConfig, seed: int = PRETRAIN_SEED) -> Path:
    """The demonstrations of ``cfg``'s arms for pretraining seed ``seed`` under ``out``,
    as collected so far."""
    return out / CACHE / "demos" / f"{demos_key(cfg, seed)}.npz"


def npz_length(path: Path) -> int:
    """How many transitions ``path`` holds (0: none, or not a transitions file)."""
    try:
        with np.load(path) as z:
            return int(z["actions"].shape[0])
    except (OSError, ValueError, KeyError, EOFError):
        return 0


@dataclass(frozen=True)
class CacheState:
    """What theta_0's cache already holds of one theta_0 (for the plan and the verbs)."""

    folder: Path
    demos_file: Path
    done: bool
    """learner.pt is there: nothing to do."""
    demos: int
    """Demonstrations on disk for it (its own demos.npz, else the shared collection)."""
    policy: bool
    """The policy's phase is done (policy.pt)."""
    rollouts: int
    """BC rollouts kept so far."""


def cache_state(out: Path, cfg: FleetConfig, critics: Iterable[str] | None,
                seed: int = PRETRAIN_SEED) -> CacheState:
    folder = theta0_folder(out, cfg, critics, seed)
    shared = demos_file(out, cfg, seed)
    own = folder / "demos.npz"
    return CacheState(folder, shared, (folder / "learner.pt").exists(),
                      npz_length(own) if own.exists() else npz_length(shared),
                      (folder / "policy.pt").exists(), npz_length(folder / "rollouts.npz"))


class PartialFile:
    """A collection kept as it goes (``pretraining.Keep``): ``before`` (kept by an
    earlier try) and this collection's pairs so far, rewritten atomically into ``path``
    at most every ``every_s`` seconds, and at once when the collection stops early."""

    def __init__(self, path: Path, before: Transitions | None, every_s: float = KEEP_EVERY_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.path, self.before, self.every_s, self._clock = path, before, every_s, clock
        self._last = clock()

    def due(self, unsaved: int) -> bool:
        return unsaved > 0 and self._clock() - self._last >= self.every_s

    def save(self, part: Transitions) -> None:
        save_transitions(part if self.before is None else concat(self.before, part), self.path)
        self._last = self._clock()


@dataclass(frozen=True)
class Report:
    """Where pretraining reports: each phase's progress, and a phase that goes on from
    what an earlier try kept (``TrialHooks.on_phase_resumed``)."""

    phase: Progress | None = None
    resumed: Progress | None = None


def as_report(progress: Progress | TrialHooks | None) -> Report:
    """A trial's hooks (both calls), a bare progress callable (it hears both), or none."""
    if isinstance(progress, TrialHooks):
        return Report(progress.on_phase, progress.on_phase_resumed)
    return Report(progress, progress)


def collect_into(path: Path, hosts: Hosts, humans: Humans, count: int, t_R: int,
                 report: Report, every_s: float = KEEP_EVERY_S) -> Transitions:
    """The demonstrations file ``path`` grown to at least ``count`` pairs (what it kept,
    then the rest, kept as they come); its first ``count`` pairs."""
    have = load_transitions(path) if path.exists() else None
    n = 0 if have is None else len(have)
    if have is not None and n >= count:
        return head(have, count)
    if n and report.resumed is not None:
        report.resumed("collect", n, count)
    keep = PartialFile(path, have, every_s)
    new = collect_demos(hosts, humans, count - n, t_R, report.phase, keep=keep, done_before=n)
    demos = new if have is None else concat(have, new)
    save_transitions(demos, path)
    return demos


@contextlib.contextmanager
def own_hosts(cfg: FleetConfig, seed: int = PRETRAIN_SEED) -> Iterator[Hosts]:
    """The fleet's hosts at the pretraining seed's world (``pretrain_hosts_seed``),
    started, then rested and closed: for a caller without a trial's hosts (``testbed
    collect``/``pretrain``, the Ray task)."""
    from testbed.experiments.build import build_hosts

    hosts = build_hosts(cfg, pretrain_hosts_seed(seed))
    try:
        hosts.start()
        yield hosts
    finally:
        try:
            hosts.rest()
        finally:
            hosts.close()


def make_theta0(cfg: FleetConfig, humans: Humans, out: Path, critics: Iterable[str] | None,
                hosts: Hosts, progress: Progress | TrialHooks | None,
                every_s: float = KEEP_EVERY_S, seed: int = PRETRAIN_SEED) -> Path:
    """theta_0 of ``cfg`` with ``critics`` pretrained from ``seed`` (the learner's
    initialisation, its sampling and the rollouts' noise) into its folder under ``out``,
    each phase going on from what the cache kept; its learner.pt. ``hosts`` are started
    and at ``pretrain_hosts_seed(seed)``."""
    report = as_report(progress)
    which = critic_set(critics)
    folder = theta0_folder(out, cfg, which, seed)
    folder.mkdir(parents=True, exist_ok=True)
    demos = _demos_for(folder, cfg, humans, out, hosts, report, every_s, seed)
    learner, trained = _policy_of(folder, cfg, seed)
    rollouts_path = folder / "rollouts.npz"
    kept = load_transitions(rollouts_path) if rollouts_path.exists() else None
    resume = Resume(policy_trained=trained, rollouts=kept,
                    keep_rollouts=PartialFile(rollouts_path, kept, every_s),
                    after_policy=lambda learner: learner.save(folder / "policy.pt"),
                    resumed=report.resumed)
    data = pretrain(learner, cfg.learning, demos, hosts, humans, cfg.algorithm.t_R,
                    seed, report.phase, critics=which, resume=resume)
    save_transitions(data, folder / "transitions.npz")
    learner.save(folder / "learner.pt")
    for done_with in ("policy.pt", "rollouts.npz"):
        (folder / done_with).unlink(missing_ok=True)
    return folder / "learner.pt"


def _demos_for(folder: Path, cfg: FleetConfig, humans: Humans, out: Path, hosts: Hosts,
               report: Report, every_s: float, seed: int = PRETRAIN_SEED) -> Transitions:
    """theta_0's demonstrations: its own demos.npz (an older cache's, or written
    before), else the first ``learning.demos`` of the shared collection, grown as
    needed, and written as its own."""
    own = folder / "demos.npz"
    if own.exists():
        return load_transitions(own)
    shared = demos_file(out, cfg, seed)
    demos = collect_into(shared, hosts, humans, cfg.learning.demos, cfg.algorithm.t_R,
                         report, every_s)
    if npz_length(shared) == len(demos):
        with contextlib.suppress(OSError):  # a file system without hard links: a copy
            os.link(shared, own)
            return demos
    save_transitions(demos, own)
    return demos


def _policy_of(folder: Path, cfg: FleetConfig, seed: int = PRETRAIN_SEED
               ) -> tuple[Any, bool]:
    """The learner pretraining goes on with: the policy checkpointed after its phase
    (True), else a new one (False)."""
    from testbed.learning import Learner

    policy = folder / "policy.pt"
    if policy.exists():
        return Learner.load(policy, cfg.learning), True
    return Learner(cfg.learning, seed=seed), False
