"""The verbs that run trials: ``trial``, ``evaluate``, ``protocol`` and ``sweep``.

Each is one ``Verb`` (its arguments and its handler together). Imported for
``testbed --help``, so the trial, torch and Ray are imported inside the handlers.
"""

from __future__ import annotations

import argparse
import json
import shlex
from pathlib import Path
from typing import TYPE_CHECKING, Any

from testbed.cli.arguments import (
    HUMANS,
    Verb,
    add_config,
    add_dry_run,
    add_fanout_arguments,
    add_trial_arguments,
    positive,
)
from testbed.cli.checks import (
    check_device,
    check_humans,
    check_out_dir,
    check_policy,
    dry_run,
    load_config,
    refused,
    resume_options,
    say_unchecked,
    trial_options,
)
from testbed.experiments.controller_gate import TrialRefused
from testbed.experiments.fleet_config import FleetConfig

if TYPE_CHECKING:
    from testbed.experiments.trial import TrialOptions


def print_summary(run_dir: Path, summary: dict[str, Any]) -> None:
    """A finished run on stdout: its folder, then its summary as JSON."""
    print(f"run: {run_dir}")
    print(json.dumps(summary, indent=2))


# ---- trial ------------------------------------------------------------------------------
def _trial_arguments(p: argparse.ArgumentParser) -> None:
    add_trial_arguments(p)
    p.add_argument("--resume", metavar="DIR", help="continue a crashed or killed trial")
    add_dry_run(p)


def cmd_trial(args: argparse.Namespace) -> int:
    from testbed.experiments.progress import TrialProgress
    from testbed.experiments.trial import run_trial

    if args.resume:
        resume = Path(args.resume)
        cfg, opts = resume_options(resume)
    else:
        resume = None
        cfg = load_config(args)
        opts = trial_options(cfg, args)
    say_trial_plan(cfg, opts, args, resume)
    if args.dry_run:
        say_unchecked()
        return 0
    try:
        with TrialProgress(opts.steps, cfg.humans.count, len(cfg.robot_names)) as bar:
            run, summary = run_trial(cfg, opts, resume=resume, hooks=bar)
    except TrialRefused as exc:
        return refused("trial", exc)
    print_summary(run.path, summary)
    return 0


def say_trial_plan(cfg: FleetConfig, opts: TrialOptions, args: argparse.Namespace,
                   resume: Path | None) -> None:
    """What the trial is about to do before step 1 and how long it takes (theta_0's
    phases it still needs, its steps), before anything moves; how to make theta_0
    ahead with the arguments that name this trial's cache (its folder of runs, its
    algorithm, its humans)."""
    from testbed.cli.theta0_verbs import ahead_arguments
    from testbed.experiments.time_plan import plan_lines, print_plan, resumed_start, trial_plan

    start = resumed_start(resume) if resume is not None else 0
    plan = trial_plan(cfg, opts, start)
    ahead = (ahead_arguments(getattr(args, "config", None), cfg, opts.algorithm, opts.out,
                             opts.humans, check_files=not dry_run(args))
             if plan.pretrains else None)
    print_plan(plan_lines(plan, opts.humans, ahead))


TRIAL = Verb(
    "trial", help="run one trial",
    description="Run one trial (default: the built-in twin fleet, 4 arms, 2 scripted "
    "humans, C.U.R., 250 steps).",
    add_arguments=_trial_arguments, run=cmd_trial)


# ---- evaluate ---------------------------------------------------------------------------
def _evaluate_arguments(p: argparse.ArgumentParser) -> None:
    add_config(p)
    p.add_argument("--policy", required=True, metavar="FILE")
    p.add_argument("--steps", type=positive, default=250, metavar="K")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", metavar="DIR")
    p.add_argument("--humans", choices=HUMANS)
    p.add_argument("--name")


def cmd_evaluate(args: argparse.Namespace) -> int:
    from testbed.experiments.progress import TrialProgress
    from testbed.experiments.trial import run_trial

    cfg = load_config(args)
    # C-prioritised hard resets, no teleop, no learning (the paper's 8.3.4)
    args.algorithm = "bc"
    opts = trial_options(cfg, args, evaluate=True)
    from testbed.records.run_dir import evaluated, evaluation_label

    source = evaluated(Path(args.policy))
    opts.name = args.name or f"eval-{Path(args.policy).parent.name or 'policy'}-s{opts.seed}"
    # the report's row: never the allocation's "bc", but what was evaluated
    opts.label = evaluation_label(source["algorithm"])
    try:
        with TrialProgress(opts.steps, cfg.humans.count, len(cfg.robot_names)) as bar:
            run, summary = run_trial(cfg, opts, hooks=bar, meta={"evaluates": source})
    except TrialRefused as exc:
        return refused("evaluate", exc)
    print_summary(run.path, summary)
    return 0


EVALUATE = Verb(
    "evaluate", help="a trained policy alone, humans for hard resets only",
    description="Run a trained policy for K steps with C-prioritised hard resets only "
    "(the paper's 8.3.4); same records and report.",
    add_arguments=_evaluate_arguments, run=cmd_evaluate)


# ---- protocol ---------------------------------------------------------------------------
def _protocol_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE")
    p.add_argument("--out", metavar="DIR", help="override the protocol's output folder")
    p.add_argument("--yes", action="store_true", help="do not prompt between trials")
    add_fanout_arguments(p)
    add_dry_run(p)


def cmd_protocol(args: argparse.Namespace) -> int:
    from testbed.experiments.protocol import load_protocol, run_protocol
    from testbed.experiments.time_plan import say_protocol_plan

    proto = load_protocol(Path(args.file), check_files=not args.dry_run)
    if args.out is not None:
        check_out_dir("--out", args.out)
    check_device(proto.fleet)
    check_humans(proto.humans, proto.fleet, available=not args.dry_run)
    # collect/pretrain --config FILE fill this very folder: the protocol's out, its humans
    say_protocol_plan(proto, Path(args.out or proto.out), f"--config {shlex.quote(args.file)}"
                      + (f" --runs {shlex.quote(args.out)}" if args.out else ""))
    if args.dry_run:
        say_unchecked()
        return 0
    if args.workers is not None or args.ray is not None:
        from testbed.experiments.fanout import run_protocol_on_ray
        from testbed.results.report import write_report

        folder = Path(args.out or proto.out)
        run_protocol_on_ray(proto, folder, address=args.ray, workers=args.workers,
                            cpus_per_trial=args.cpus_per_trial)
        report = write_report([folder], folder,
                              proto.until.reference if proto.until is not None else None)
    else:
        try:
            report = run_protocol(proto, out=args.out, ask=not args.yes, plan=False)
        except TrialRefused as exc:
            return refused("protocol", exc)
    print(report.markdown)
    print(f"report: {report.folder}")
    return 0


PROTOCOL = Verb(
    "protocol", help="run a protocol file end to end, then its report",
    description="Run trials x algorithms x steps of a protocol, then report.",
    add_arguments=_protocol_arguments, run=cmd_protocol)


# ---- sweep ------------------------------------------------------------------------------
def _sweep_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE")
    p.add_argument("--out", metavar="DIR", help="override the sweep's output folder")
    add_fanout_arguments(p)


def cmd_sweep(args: argparse.Namespace) -> int:
    from testbed.experiments.sweep import load_sweep, run_sweep

    sweep = load_sweep(Path(args.file))
    if args.out is not None:
        check_out_dir("--out", args.out)
    for run in sweep.runs():
        check_device(run.fleet)
        check_humans(sweep.humans, run.fleet)
        if sweep.policy is not None:
            check_policy(sweep.policy, run.fleet, f"{args.file}: policy")
    if args.workers is not None or args.ray is not None:
        from testbed.experiments.fanout import run_sweep_on_ray

        run_sweep_on_ray(sweep, Path(args.out) if args.out else sweep.folder,
                         address=args.ray, workers=args.workers,
                         cpus_per_trial=args.cpus_per_trial)
    try:  # every run finished: skipped, then the report
        report = run_sweep(sweep, out=args.out)
    except TrialRefused as exc:
        return refused("sweep", exc)
    print(report.markdown)
    print(f"report: {report.folder} (figure: curves.png)")
    return 0


SWEEP = Verb(
    "sweep", help="a grid over config fields x seeds, then its figure",
    description="Run every grid point x seed of a sweep file (e.g. "
    "protocols/sweeps/humans.toml), then report: one line per value, mean +- std over "
    "seeds, as the paper's figures 6-9.",
    add_arguments=_sweep_arguments, run=cmd_sweep)
