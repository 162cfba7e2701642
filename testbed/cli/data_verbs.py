"""The verbs about data and what is learnt from it: ``collect``, ``pretrain``,
``export``, ``train`` and ``report``.

Each is one ``Verb`` (its arguments and its handler together). Imported for
``testbed --help``, so torch, the hosts and the dataset writers are imported inside the
handlers.
"""

from __future__ import annotations

import argparse
import zipfile
from pathlib import Path

from testbed.cli.arguments import HUMANS, Verb, add_config, positive
from testbed.cli.checks import (
    check_device,
    check_humans,
    check_out_dir,
    check_out_file,
    load_config,
    with_pretrain_steps,
)
from testbed.core.config import ConfigError


# ---- collect ----------------------------------------------------------------------------
def _collect_arguments(p: argparse.ArgumentParser) -> None:
    add_config(p)
    p.add_argument("--count", type=positive, help="pairs (default: config learning.demos)")
    p.add_argument("--humans", choices=HUMANS)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="demos.npz", metavar="NPZ")


def cmd_collect(args: argparse.Namespace) -> int:
    from testbed.experiments.build import build_hosts, make_humans
    from testbed.experiments.pretraining import collect_demos, save_transitions
    from testbed.experiments.progress import TrialProgress

    cfg = load_config(args)
    count = args.count or cfg.learning.demos
    check_out_file("--out", args.out)
    check_humans(args.humans or cfg.humans.kind, cfg)
    humans = make_humans(args.humans or cfg.humans.kind, cfg.humans.count, cfg.humans.web,
                         names=[p.name for p in cfg.humans.people])
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


COLLECT = Verb(
    "collect", help="offline demonstrations (375 pairs by default)",
    description="Humans drive every arm; keep the state-action pairs.",
    add_arguments=_collect_arguments, run=cmd_collect)


# ---- pretrain ---------------------------------------------------------------------------
def _pretrain_arguments(p: argparse.ArgumentParser) -> None:
    add_config(p)
    p.add_argument("--demos", required=True, metavar="NPZ")
    p.add_argument("--humans", choices=HUMANS)
    p.add_argument("--steps", type=int,
                   help="gradient steps of each phase, policy and critics (default: config)")
    p.add_argument("--out", default="learner.pt", metavar="PT")


def cmd_pretrain(args: argparse.Namespace) -> int:
    from testbed.experiments.build import build_hosts, make_humans
    from testbed.experiments.learners import PRETRAIN_SEED, new_learner
    from testbed.experiments.pretraining import load_transitions, pretrain
    from testbed.experiments.progress import TrialProgress

    cfg = with_pretrain_steps(load_config(args), args.steps)
    if not Path(args.demos).is_file():
        raise ConfigError(f"--demos: no such file {args.demos!r}; run testbed collect first")
    check_out_file("--out", args.out)
    check_device(cfg)
    check_humans(args.humans or cfg.humans.kind, cfg, teleop=False)
    try:
        demos = load_transitions(Path(args.demos))
    except ConfigError:
        raise
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:  # not an .npz
        why = " ".join(str(exc).split())[:160]
        raise ConfigError(f"--demos: {args.demos} is not a demonstrations file ({why}); "
                          "give the .npz of testbed collect") from None
    humans = make_humans(args.humans or cfg.humans.kind, cfg.humans.count, cfg.humans.web,
                         names=[p.name for p in cfg.humans.people])
    hosts = build_hosts(cfg, PRETRAIN_SEED)
    learner = new_learner(cfg, PRETRAIN_SEED)
    try:
        hosts.start()
        with TrialProgress(cfg.learning.pretrain_steps, 0, 0, label="pretrain") as bar:
            # both critics: this learner.pt may serve any algorithm
            pretrain(learner, cfg.learning, demos, hosts, humans, cfg.algorithm.t_R,
                     PRETRAIN_SEED, bar.on_phase, critics=None)
    finally:
        hosts.close()
        humans.close()
    learner.save(Path(args.out))
    print(f"learner -> {args.out}")
    return 0


PRETRAIN = Verb(
    "pretrain", help="pretrain policy and critics from demonstrations",
    description="Train the policy on demos, roll it out for the critics' data, train the "
    "critics; write learner.pt.",
    add_arguments=_pretrain_arguments, run=cmd_pretrain)


# ---- export -----------------------------------------------------------------------------
def _export_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dirs", nargs="+", metavar="RUN_OR_PROTOCOL_DIR")
    p.add_argument("--format", choices=["lerobot", "npz"], default="lerobot",
                   help="lerobot (default; needs the export extra) or npz (numpy only)")
    p.add_argument("--out", required=True, metavar="DIR_OR_FILE",
                   help="lerobot: a new or empty folder; npz: a .npz file, or a folder "
                   "to hold frames.npz")
    p.add_argument("--images", choices=["png", "video"],
                   help="lerobot only: png (default: lossless, PNG bytes in the parquet) "
                   "or video (H.264 MP4, smaller for camera images, lossy)")


def cmd_export(args: argparse.Namespace) -> int:
    from testbed.datasets.dataset_io import export

    out = Path(args.out)
    if args.format == "npz":
        if args.images is not None:
            raise ConfigError("--images: only for --format lerobot (npz keeps the raw "
                              "uint8 images)")
        if out.suffix == ".npz":
            check_out_file("--out", args.out)
        else:
            check_out_dir("--out", args.out)
    elif out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"--out: {args.out!r} exists and is not an empty folder; a "
                          "LeRobot dataset goes to a new folder")
    result = export([Path(d) for d in args.dirs], args.format, out, args.images or "png")
    print(f"{result.frames} frames, {result.episodes} episodes ({result.demo_episodes} of "
          f"offline demonstrations) from {result.runs} run(s) -> {result.path}")
    return 0


EXPORT = Verb(
    "export", help="runs' frames as a LeRobot v3 dataset or numpy arrays",
    description="Cut the runs' data stores into episodes (one arm, one goal) with every "
    "label (who acted, intervention, success, violation, uncertainty, risk) and theta_0's "
    "demonstrations, and write them as a LeRobot v3 dataset or one npz.",
    add_arguments=_export_arguments, run=cmd_export)


# ---- train ------------------------------------------------------------------------------
def _train_arguments(p: argparse.ArgumentParser) -> None:
    add_config(p)
    p.add_argument("--data", required=True, nargs="+", metavar="DIR")
    p.add_argument("--steps", type=int,
                   help="gradient steps of each phase, policy and critics (default: config)")
    p.add_argument("--out", default="learner.pt", metavar="PT")


def cmd_train(args: argparse.Namespace) -> int:
    from testbed.datasets.dataset_io import load_frames
    from testbed.datasets.sources import DEMO_FIELDS
    from testbed.datasets.training import TrainingData, training_data
    from testbed.experiments.learners import PRETRAIN_SEED, new_learner
    from testbed.experiments.progress import TrialProgress

    cfg = with_pretrain_steps(load_config(args), args.steps)
    check_out_file("--out", args.out)
    check_device(cfg)
    for d in args.data:
        if not Path(d).exists():
            raise ConfigError(f"--data: no such file or folder {d!r}")
    data = TrainingData.merge([training_data(load_frames(Path(d))) for d in args.data])
    if len(data.actions) == 0:
        raise ConfigError(f"--data: no human-labelled frame in {', '.join(args.data)}; "
                          "nothing to train the policy on")
    from testbed.learning import Transitions

    transitions = Transitions.build(*(data.transitions[k] for k in DEMO_FIELDS))
    learner = new_learner(cfg, PRETRAIN_SEED)
    with TrialProgress(cfg.learning.pretrain_steps, 0, 0, label="train") as bar:
        # both critics, as testbed pretrain: this learner.pt may serve any algorithm
        learner.pretrain(data.images, data.actions,
                         transitions=transitions if len(transitions) else None,
                         demo_humans=data.humans,
                         progress=lambda phase, done, total: bar.on_phase(
                             f"train {phase}", done, total))
    learner.save(Path(args.out))
    print(f"{len(data.actions)} labelled frames, {len(transitions)} transitions -> "
          f"learner {args.out}")
    return 0


TRAIN = Verb(
    "train", help="pretrain a learner from exported data",
    description="Pretrain policy and critics from exported datasets (testbed export's npz "
    "or LeRobot folders, or run folders; several are merged): the human-labelled frames "
    "and the demonstrations for the policy, every push with its next frame for the "
    "critics; write learner.pt (testbed evaluate --policy).",
    add_arguments=_train_arguments, run=cmd_train)


# ---- report -----------------------------------------------------------------------------
def _report_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dirs", nargs="+", metavar="RUN_OR_PROTOCOL_DIR")
    p.add_argument("--out", metavar="DIR", help="where to write the report (default: first dir)")
    p.add_argument("--reference", metavar="ALGORITHM_OR_POINT",
                   help="what every other algorithm (or sweep point) is compared with, "
                        "paired by trial (default: cur; a sweep: its grid's first point)")


def cmd_report(args: argparse.Namespace) -> int:
    from testbed.experiments.report import write_report

    dirs = [Path(d) for d in args.dirs]
    for d in dirs:
        if not d.is_dir():
            raise ConfigError(f"RUN_OR_PROTOCOL_DIR: no such folder {str(d)!r}")
    if args.out is not None:
        check_out_dir("--out", args.out)
    report = write_report(dirs, Path(args.out) if args.out else dirs[0],
                          reference=args.reference)
    print(report.markdown)
    print(f"report: {report.folder}")
    return 0


REPORT = Verb(
    "report", help="tables and plots of runs or protocol folders",
    description="Per algorithm (or sweep point): mean +- std, 95% intervals, paired "
    "comparisons against a reference with exact sign-flip p-values, the humans by name; "
    "report.md, report.html (one self-contained page with the curves and the runs' "
    "metadata), CSVs, curves.png.",
    add_arguments=_report_arguments, run=cmd_report)
