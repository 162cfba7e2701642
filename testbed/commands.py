"""What each ``testbed`` verb does, given its parsed arguments.

Kept apart from ``cli.py`` so that ``testbed --help`` imports nothing heavy; these
functions import drivers, torch and the console only when a verb needs them.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rich.console import Console

from testbed.config import ConfigError, FleetConfig, load_config
from testbed.priorities import ALGORITHM_NAMES
from testbed.progress import TrialProgress
from testbed.trial import TrialOptions, run_trial

console = Console(stderr=True)


def _config(args: argparse.Namespace) -> FleetConfig:
    return load_config(getattr(args, "config", None))


def _check_algorithm(name: str) -> None:
    if name not in ALGORITHM_NAMES:
        raise ConfigError(
            f"--algorithm (or algorithm.name): unknown algorithm {name!r}; "
            f"use one of {', '.join(ALGORITHM_NAMES)}"
        )


def trial_options(cfg: FleetConfig, args: argparse.Namespace, **over: Any) -> TrialOptions:
    opts = TrialOptions(
        algorithm=args.algorithm or cfg.algorithm.name,
        steps=args.steps or cfg.trial.steps,
        seed=cfg.trial.seed if args.seed is None else args.seed,
        out=args.out or cfg.trial.out,
        humans=args.humans or cfg.humans.kind,
        policy=getattr(args, "policy", None),
        name=getattr(args, "name", None),
    )
    for k, v in over.items():
        setattr(opts, k, v)
    _check_algorithm(opts.algorithm)
    if opts.policy is not None and not Path(opts.policy).is_file():
        raise ConfigError(f"--policy: no such file {opts.policy!r}; give a learner.pt")
    return opts


def print_summary(run_dir: Path, summary: dict[str, Any]) -> None:
    print(f"run: {run_dir}")
    print(json.dumps(summary, indent=2))


def cmd_trial(args: argparse.Namespace) -> int:
    if args.resume:
        resume = Path(args.resume)
        if not resume.is_dir():
            raise ConfigError(f"--resume: no such run folder {args.resume!r}")
        from testbed.runs import RunDir

        cfg = RunDir(resume).read_config()
        opts = TrialOptions(**RunDir(resume).read_meta()["options"])
    else:
        resume = None
        cfg = _config(args)
        opts = trial_options(cfg, args)
    with TrialProgress(opts.steps, cfg.humans.count, len(cfg.robot_names)) as bar:
        run, summary = run_trial(cfg, opts, resume=resume, on_step=bar.on_step,
                                 progress=bar.on_phase)
    print_summary(run.path, summary)
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    cfg = _config(args)
    args.algorithm = "bc"  # C-prioritised hard resets, no teleop, no learning (seed 8.3.4)
    opts = trial_options(cfg, args, evaluate=True)
    opts.name = args.name or f"eval-{Path(args.policy).parent.name or 'policy'}-s{opts.seed}"
    with TrialProgress(opts.steps, cfg.humans.count, len(cfg.robot_names)) as bar:
        run, summary = run_trial(cfg, opts, on_step=bar.on_step, progress=bar.on_phase)
    print_summary(run.path, summary)
    return 0


def cmd_protocol(args: argparse.Namespace) -> int:
    from testbed.protocol import load_protocol, run_protocol

    proto = load_protocol(Path(args.file))
    report = run_protocol(proto, out=args.out, ask=not args.yes)
    print(report.markdown)
    print(f"report: {report.folder}")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from testbed.report import write_report

    dirs = [Path(d) for d in args.dirs]
    for d in dirs:
        if not d.is_dir():
            raise ConfigError(f"RUN_OR_PROTOCOL_DIR: no such folder {str(d)!r}")
    report = write_report(dirs, Path(args.out) if args.out else dirs[0])
    print(report.markdown)
    print(f"report: {report.folder}")
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    from testbed.preflight import preflight

    cfg = _config(args)
    ok = preflight(cfg, Path(args.mosaic), print_line=print)
    return 0 if ok else 1


def cmd_collect(args: argparse.Namespace) -> int:
    from testbed.humans import make_humans
    from testbed.offline import collect_demos, save_transitions
    from testbed.trial import build_hosts

    cfg = _config(args)
    count = args.count or cfg.learning.demos
    humans = make_humans(args.humans or cfg.humans.kind, cfg.humans.count)
    hosts = build_hosts(cfg, args.seed)
    try:
        hosts.start()
        with TrialProgress(count, 0, 0, label="collect") as bar:
            demos = collect_demos(hosts, humans, count, cfg.algorithm.t_R, bar.on_phase)
    finally:
        hosts.close()
        humans.close()
    save_transitions(demos, Path(args.out))
    print(f"{len(demos)} state-action pairs -> {args.out}")
    return 0


def cmd_pretrain(args: argparse.Namespace) -> int:
    from testbed.humans import make_humans
    from testbed.offline import load_transitions, pretrain
    from testbed.trial import PRETRAIN_SEED, build_hosts, new_learner

    cfg = _config(args)
    if not Path(args.demos).is_file():
        raise ConfigError(f"--demos: no such file {args.demos!r}; run testbed collect first")
    if args.steps is not None:
        if args.steps < 0:
            raise ConfigError("--steps: must be >= 0")
        cfg = cfg.model_copy(
            update={"learning": cfg.learning.model_copy(
                update={"pretrain_steps": args.steps, "critic_pretrain_steps": None})}
        )
    demos = load_transitions(Path(args.demos))
    humans = make_humans(args.humans or cfg.humans.kind, cfg.humans.count)
    hosts = build_hosts(cfg, PRETRAIN_SEED)
    learner = new_learner(cfg, PRETRAIN_SEED)
    try:
        hosts.start()
        with TrialProgress(cfg.learning.pretrain_steps, 0, 0, label="pretrain") as bar:
            pretrain(learner, cfg.learning, demos, hosts, humans, cfg.algorithm.t_R,
                     PRETRAIN_SEED, bar.on_phase)
    finally:
        hosts.close()
        humans.close()
    learner.save(Path(args.out))
    print(f"learner -> {args.out}")
    return 0


VERBS: dict[str, Callable[[argparse.Namespace], int]] = {
    "trial": cmd_trial,
    "evaluate": cmd_evaluate,
    "protocol": cmd_protocol,
    "report": cmd_report,
    "check": cmd_check,
    "collect": cmd_collect,
    "pretrain": cmd_pretrain,
}
