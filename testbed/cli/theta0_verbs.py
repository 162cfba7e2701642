"""The verbs that make theta_0 ahead of a trial: ``collect`` and ``pretrain``.

Why: a physical trial's theta_0 is hours of teleoperated demonstrations, policy pushes
and gradient steps before step 1 (issue 44). These are its named, resumable steps on
the lab's arms: with ``--config`` and no file argument they fill the very cache the
trial or protocol of that config reads (``testbed.experiments.theta0``), so ``testbed
collect --config protocols/physical.toml``, then ``testbed pretrain --config ...``, then
``testbed protocol ...`` collects and pretrains once. Each prints its estimate first
(``testbed.experiments.time_plan``), shows its progress with an ETA, and, cut short, goes
on from what it kept when run again. With a file argument (``collect --out NPZ``,
``pretrain --demos NPZ``) they work on files, as they always did.

Imported for ``testbed --help``: the hosts, torch and the protocol are imported inside.
"""

from __future__ import annotations

import argparse
import shlex
import shutil
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

from testbed.cli.arguments import HUMANS, Verb, add_config, add_dry_run, positive
from testbed.cli.checks import (
    check_algorithm,
    check_device,
    check_humans,
    check_out_dir,
    check_out_file,
    dry_run,
    load_config,
    say_unchecked,
    with_pretrain_steps,
)
from testbed.core.config import ConfigError
from testbed.experiments.fleet_config import FleetConfig

if TYPE_CHECKING:
    from testbed.core.hosts import Hosts
    from testbed.core.humans import Humans
    from testbed.experiments.progress import TrialProgress
    from testbed.experiments.protocol import Protocol
    from testbed.experiments.theta0 import Theta0Spec

T = TypeVar("T")


@dataclass(frozen=True)
class _Cache:
    """The cache the trial or protocol of ``--config`` reads, and what it needs there."""

    folder: Path
    humans: str
    targets: list[Theta0Spec]
    """Each theta_0: its fleet, its critics, a label ("" for one alone), its seed (a
    protocol with ``pretrain_per_trial``: one per trial, each from its trial's seed)."""


def _add_cache_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", metavar="DIR", help="the folder of runs whose cache to fill "
                   "(default: the protocol's out, or the config's trial.out)")
    add_dry_run(p)


def _cache_of(args: argparse.Namespace) -> _Cache:
    """What ``--config`` (a protocol: every theta_0 its runs start from, the critics
    any of its algorithms reads, one per trial with ``pretrain_per_trial``; a fleet
    config, or a protocol with ``--algorithm``: the trial's of that config, for
    ``--algorithm``) needs in its folder of runs."""
    from testbed.experiments.pretraining import critic_set
    from testbed.experiments.theta0 import Theta0Spec
    from testbed.fleet.algorithms import ALGORITHMS

    algorithm = getattr(args, "algorithm", None)
    proto = _protocol_of(args.config, check_files=not dry_run(args))
    if proto is not None and algorithm is None:
        from testbed.experiments.time_plan import protocol_targets

        targets = protocol_targets(proto)
    else:  # the trial's: testbed trial --config FILE [--algorithm NAME]
        cfg = load_config(args)
        name = algorithm or cfg.algorithm.name
        check_algorithm(name)
        targets = [Theta0Spec(cfg, critic_set(ALGORITHMS[name].critics))]
    first = targets[0].cfg
    folder = Path(args.runs or (proto.out if proto is not None else first.trial.out))
    humans = args.humans or (proto.humans if proto is not None else first.humans.kind)
    check_out_dir("--runs", str(folder))
    return _Cache(folder, humans, targets)


def _protocol_of(config: str | None, *, check_files: bool) -> Protocol | None:
    """The protocol of ``--config`` when it names a protocol file, else None."""
    from testbed.core.config import read_toml
    from testbed.experiments.fleet_config import file_kind

    if config is None or file_kind(read_toml(config)) != "protocol":
        return None
    from testbed.experiments.protocol import load_protocol

    return load_protocol(Path(config), check_files=check_files)


def ahead_arguments(config: str | None, cfg: FleetConfig, algorithm: str, out: str,
                    humans: str, *, check_files: bool = True) -> str:
    """The arguments of ``testbed collect``/``pretrain`` that fill the very cache
    ``testbed trial --config config --algorithm algorithm --out out --humans humans``
    reads (``cfg``: its fleet): each one that differs from what collect and pretrain
    take by default (a protocol file's out and humans are not a trial's: named), and
    always a folder or a config, without which collect writes a file instead."""
    proto = _protocol_of(config, check_files=check_files)
    parts = [f"--config {shlex.quote(config)}"] if config else []
    if proto is not None or algorithm != cfg.algorithm.name:
        parts.append(f"--algorithm {algorithm}")
    if config is None or Path(out) != Path(proto.out if proto is not None else cfg.trial.out):
        parts.append(f"--runs {shlex.quote(out)}")
    if humans != (proto.humans if proto is not None else cfg.humans.kind):
        parts.append(f"--humans {humans}")
    return " ".join(parts)


def _humans(kind: str, cfg: FleetConfig, folder: Path | None = None) -> Humans:
    """The humans of a collection or a pretraining; a browser console's links are those
    of the folder of runs ``folder`` (the trial's and protocol's of that folder, kept in
    its web-links.json: ``testbed.experiments.web_links``)."""
    from testbed.experiments.build import make_humans

    web = cfg.humans.web
    if kind == "web" and folder is not None:
        from testbed.experiments.web_links import links_for_folder
        from testbed.people.people_config import WebConsoleConfig

        web = links_for_folder(folder, web or WebConsoleConfig(), cfg.humans.count)
    return make_humans(kind, cfg.humans.count, web,
                       names=[p.name for p in cfg.humans.people])


# ---- collect ----------------------------------------------------------------------------
def _collect_arguments(p: argparse.ArgumentParser) -> None:
    add_config(p)
    p.add_argument("--count", type=positive, help="pairs (default: config learning.demos)")
    p.add_argument("--humans", choices=HUMANS)
    p.add_argument("--seed", type=int, help="with --out: the hosts' seed (default 0)")
    p.add_argument("--algorithm", metavar="NAME", help="with a protocol file: collect for "
                   "the trial of its [fleet] (testbed trial --config FILE --algorithm NAME) "
                   "rather than for its protocol; a fleet config's demonstrations are every "
                   "algorithm's")
    p.add_argument("--out", metavar="NPZ", help="write the pairs to this file (default "
                   "without --config or --runs: demos.npz); with either and no --out they "
                   "go to the cache its trial or protocol reads, kept as they come")
    _add_cache_arguments(p)


def cmd_collect(args: argparse.Namespace) -> int:
    if args.out is not None or (args.config is None and args.runs is None):
        return _collect_file(args)
    from testbed.experiments.theta0 import as_report, collect_into, demos_file, npz_length
    from testbed.experiments.time_plan import collect_plan, plan_lines, print_plan

    if args.seed is not None:
        raise ConfigError("--seed: the cache's demonstrations are collected at the "
                          "pretraining seed (the trial's); give --out NPZ for another")
    cache = _cache_of(args)
    files: dict[Path, tuple[FleetConfig, int, int]] = {}
    for cfg, _, _, seed in cache.targets:  # one per set of arms and seed, the most asked
        path = demos_file(cache.folder, cfg, seed)
        count = args.count or max(cfg.learning.demos, files.get(path, (cfg, 0, seed))[1])
        files[path] = (cfg, count, seed)
    for path, (cfg, count, _) in files.items():
        check_humans(cache.humans, cfg, available=not args.dry_run)
        print_plan(plan_lines(collect_plan(cfg, count, npz_length(path), path, cache.folder),
                              cache.humans, None))
    if args.dry_run:
        say_unchecked()
        return 0
    for path, (cfg, count, seed) in files.items():
        have = npz_length(path)
        with _progress(count, "collect") as bar:
            demos = _on_own_hosts(cfg, cache.humans, cache.folder,
                                  lambda hosts, humans, c=cfg, p=path, n=count, b=bar:
                                  collect_into(p, hosts, humans, n, c.algorithm.t_R,
                                               as_report(b)), seed)
        print(f"{min(len(demos), count)} state-action pairs ({min(have, count)} kept from "
              f"before) -> {path}")
    return 0


def _collect_file(args: argparse.Namespace) -> int:
    """``testbed collect --out NPZ`` (or without ``--config``): the pairs as one file."""
    from testbed.experiments.build import build_hosts
    from testbed.experiments.pretraining import collect_demos, save_transitions
    from testbed.experiments.time_plan import collect_plan, plan_lines, print_plan

    if args.runs is not None:
        raise ConfigError("--runs: only without --out (the cache of a folder of runs)")
    cfg = load_config(args)
    out = args.out or "demos.npz"
    count = args.count or cfg.learning.demos
    check_out_file("--out", out)
    kind = args.humans or cfg.humans.kind
    check_humans(kind, cfg, available=not args.dry_run)
    print_plan(plan_lines(collect_plan(cfg, count, 0, Path(out), Path(cfg.trial.out)), kind,
                          None))
    if args.dry_run:
        say_unchecked()
        return 0
    humans = _humans(kind, cfg)
    hosts = build_hosts(cfg, 0 if args.seed is None else args.seed)
    try:
        hosts.start()
        with _progress(count, "collect") as bar:
            demos = collect_demos(hosts, humans, count, cfg.algorithm.t_R, bar.on_phase)
    finally:
        hosts.close()
        humans.close()
    save_transitions(demos, Path(out))
    print(f"{len(demos)} state-action pairs -> {out}")
    return 0


def _progress(total: int, label: str) -> TrialProgress:
    from testbed.experiments.progress import TrialProgress

    return TrialProgress(total, 0, 0, label=label)


def _on_own_hosts(cfg: FleetConfig, kind: str, folder: Path,
                  work: Callable[[Hosts, Humans], T], seed: int | None = None) -> T:
    """``work(hosts, humans)`` on the fleet's own hosts at the pretraining seed ``seed``'s
    world (default ``PRETRAIN_SEED``'s: the trial's pretraining world), then the arms at
    rest and the humans closed; the humans' links are those of the folder of runs
    ``folder``."""
    from testbed.experiments.theta0 import PRETRAIN_SEED, own_hosts

    humans = _humans(kind, cfg, folder)
    try:
        with own_hosts(cfg, PRETRAIN_SEED if seed is None else seed) as hosts:
            return work(hosts, humans)
    finally:
        humans.close()


COLLECT = Verb(
    "collect", help="offline demonstrations, into theta_0's cache (375 pairs by default)",
    description="Humans drive every arm; keep the state-action pairs. With --config (and "
    "no --out) they go to the cache its trial or protocol reads, kept as they come: run "
    "it again after a stop and it goes on; the trial then does not collect again.",
    add_arguments=_collect_arguments, run=cmd_collect)


# ---- pretrain ---------------------------------------------------------------------------
def _pretrain_arguments(p: argparse.ArgumentParser) -> None:
    add_config(p)
    p.add_argument("--demos", metavar="NPZ", help="pretrain from this file (testbed collect "
                   "--out) and write --out; without it: the theta_0 the trial or protocol "
                   "of --config starts from, into its cache (collecting what it lacks)")
    p.add_argument("--humans", choices=HUMANS)
    p.add_argument("--steps", type=int, help="with --demos: gradient steps of each phase, "
                   "policy and critics (default: config)")
    p.add_argument("--algorithm", metavar="NAME", help="the trial algorithm whose critics "
                   "theta_0 pretrains (default: the config's; a protocol file: those any of "
                   "its algorithms reads, unless NAME: then the theta_0 of testbed trial "
                   "--config FILE --algorithm NAME)")
    p.add_argument("--out", metavar="PT", help="with --demos: the learner (default "
                   "learner.pt); without: also a copy of theta_0 here")
    _add_cache_arguments(p)


def cmd_pretrain(args: argparse.Namespace) -> int:
    if args.demos is not None:
        return _pretrain_file(args)
    from testbed.experiments.theta0 import cache_state, make_theta0
    from testbed.experiments.time_plan import plan_lines, print_plan, theta0_plan

    if args.steps is not None:
        raise ConfigError("--steps: only with --demos; theta_0's cache takes the config's "
                          "pretrain_steps (the trial finds it by them)")
    if args.out is not None:
        check_out_file("--out", args.out)
    cache = _cache_of(args)
    for cfg, critics, _, seed in cache.targets:
        check_device(cfg)
        st = cache_state(cache.folder, cfg, critics, seed)
        check_humans(cache.humans, cfg, teleop=st.demos < cfg.learning.demos and not st.done,
                     available=not args.dry_run)
    print_plan(plan_lines(theta0_plan(cache.targets, cache.folder), cache.humans, None))
    if args.dry_run:
        say_unchecked()
        return 0
    made: list[Path] = []
    for cfg, critics, label, seed in cache.targets:
        st = cache_state(cache.folder, cfg, critics, seed)
        if not st.done:
            with _progress(cfg.learning.pretrain_steps, "pretrain") as bar:
                _on_own_hosts(cfg, cache.humans, cache.folder,
                              lambda hosts, humans, c=cfg, w=critics, b=bar, s=seed:
                              make_theta0(c, humans, cache.folder, w, hosts, b, seed=s),
                              seed)
        made.append(st.folder / "learner.pt")
        which = ", ".join(critics) or "no critic"
        print(f"theta_0 ({which}{'; ' + label if label else ''}) -> {made[-1]}")
    if args.out is not None:
        shutil.copyfile(made[0], args.out)
        print(f"learner -> {args.out}")
    return 0


def _pretrain_file(args: argparse.Namespace) -> int:
    """``testbed pretrain --demos NPZ``: a learner from a demonstrations file, written to
    ``--out`` (both critics: it may serve any algorithm)."""
    from testbed.experiments.build import build_hosts
    from testbed.experiments.learners import PRETRAIN_SEED, new_learner
    from testbed.experiments.pretraining import load_transitions, pretrain

    if args.runs is not None or args.algorithm is not None:
        raise ConfigError(f"{'--runs' if args.runs else '--algorithm'}: only without "
                          "--demos (theta_0 into a trial's cache)")
    cfg = with_pretrain_steps(load_config(args), args.steps)
    out = args.out or "learner.pt"
    if not Path(args.demos).is_file():
        raise ConfigError(f"--demos: no such file {args.demos!r}; run testbed collect first")
    check_out_file("--out", out)
    check_device(cfg)
    kind = args.humans or cfg.humans.kind
    check_humans(kind, cfg, teleop=False, available=not args.dry_run)
    try:
        demos = load_transitions(Path(args.demos))
    except ConfigError:
        raise
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:  # not an .npz
        why = " ".join(str(exc).split())[:160]
        raise ConfigError(f"--demos: {args.demos} is not a demonstrations file ({why}); "
                          "give the .npz of testbed collect") from None
    _print_file_plan(cfg, kind, Path(args.demos), len(demos))
    if args.dry_run:
        say_unchecked()
        return 0
    humans = _humans(kind, cfg)
    hosts = build_hosts(cfg, PRETRAIN_SEED)
    learner = new_learner(cfg, PRETRAIN_SEED)
    try:
        hosts.start()
        with _progress(cfg.learning.pretrain_steps, "pretrain") as bar:
            # both critics: this learner.pt may serve any algorithm
            pretrain(learner, cfg.learning, demos, hosts, humans, cfg.algorithm.t_R,
                     PRETRAIN_SEED, bar.on_phase, critics=None)
    finally:
        hosts.close()
        humans.close()
    learner.save(Path(out))
    print(f"learner -> {out}")
    return 0


def _print_file_plan(cfg: FleetConfig, kind: str, demos: Path, count: int) -> None:
    """``pretrain --demos``' plan: its demonstrations are given, the rest as theta_0's."""
    from testbed.experiments.time_plan import file_plan, plan_lines, print_plan

    print_plan(plan_lines(file_plan(cfg, demos, count), kind, None))


PRETRAIN = Verb(
    "pretrain", help="theta_0: policy and critics from demonstrations, into its cache",
    description="Train the policy on the demonstrations, roll it out for the critics' data, "
    "train the critics. With --config (and no --demos): the theta_0 its trial or protocol "
    "starts from, into the cache it reads (collecting the demonstrations it lacks; a "
    "stopped one goes on from what it kept); with --demos NPZ: write learner.pt.",
    add_arguments=_pretrain_arguments, run=cmd_pretrain)
