"""The verbs about data and what is learnt from it: ``export``, ``train``, ``report``
and ``plan`` (``collect`` and ``pretrain``, theta_0's steps: ``theta0_verbs``).

Each is one ``Verb`` (its arguments and its handler together). Imported for
``testbed --help``, so torch, the hosts and the dataset writers are imported inside the
handlers.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from testbed.cli.arguments import Verb, add_config, positive
from testbed.cli.checks import (
    check_device,
    check_out_dir,
    check_out_file,
    load_config,
    with_pretrain_steps,
)
from testbed.core.config import ConfigError


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
                         demo_labellers=data.labellers,
                         labeller_names=data.labeller_names,
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


# ---- values -----------------------------------------------------------------------------
def _values_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", metavar="RUN_DIR")
    p.add_argument("--checkpoint", metavar="PT",
                   help="the learner whose value critic values the pushes (default: the "
                   "run's final learner.pt)")
    p.add_argument("--truth", type=int, default=0, metavar="N",
                   help="also check the advantage against the PyBullet twin's truth on N "
                   "states no trial saw (testbed/lab/advantage_truth.py)")


def cmd_values(args: argparse.Namespace) -> int:
    from testbed.records.push_values import summary_lines, value_run, write_push_values
    from testbed.records.store import RunData, RunDataError

    run = Path(args.run)
    try:
        RunData.of_run(run).robots  # noqa: B018 (reads meta.json: is this a run's data?)
    except (RunDataError, OSError) as exc:
        raise ConfigError(f"RUN_DIR: {args.run!r} holds no run data ({exc})") from None
    pt = Path(args.checkpoint) if args.checkpoint else run / "learner.pt"
    if not pt.is_file():
        raise ConfigError(f"--checkpoint: no such file {str(pt)!r}")
    if args.truth < 0:
        raise ConfigError(f"--truth: {args.truth} states; give 0 (no check) or more")
    from testbed.learning import Learner

    learner = Learner.load(pt)
    if learner.value_updates == 0:
        raise ConfigError(f"--checkpoint: {pt}'s value critic never trained (none "
                          "pretrained, none trained online): its advantages would "
                          "mean nothing; value with a learner that has one")
    values = value_run(run, learner.push_values, learner.pre_intervention_steps)
    path = write_push_values(run, values, pt)
    print(f"{len(values['t'])} pushes valued with {pt} -> {path}")
    for line in summary_lines(values):
        print(f"  {line}")
    if args.truth:
        from testbed.lab.advantage_truth import check_on_twin

        print(check_on_twin(learner.push_values, args.truth).line())
    return 0


VALUES = Verb(
    "values", help="the value and advantage of every push of a run",
    description="Value every push of a run (demonstrations' learner, robot and human "
    "pushes alike) with a learner's value critic: Q(s, a), V(s) = Q(s, pi(s)) "
    "and the advantage A = Q - V, into the run's push_values.npz (with the checkpoint's "
    "sha256), and a summary by who pushed and by class; --truth N checks the advantage "
    "against the twin's truth.",
    add_arguments=_values_arguments, run=cmd_values)


# ---- report -----------------------------------------------------------------------------
def _report_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dirs", nargs="+", metavar="RUN_OR_PROTOCOL_DIR")
    p.add_argument("--out", metavar="DIR", help="where to write the report (default: first dir)")
    p.add_argument("--reference", metavar="ALGORITHM_OR_POINT",
                   help="what every other algorithm (or sweep point) is compared with, "
                        "paired by trial (default: cur; a sweep: its grid's first point)")


def cmd_report(args: argparse.Namespace) -> int:
    from testbed.results.report import write_report

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


# ---- plan -------------------------------------------------------------------------------
TRIALS_METRICS = ["successes", "hard_resets", "idle_time", "human_actions", "rohe"]
"""The report's metrics (``testbed.results.report.METRICS``), named here so that
``testbed --help`` imports no report."""
TRIALS_DEFAULTS = {"metric": "rohe", "alpha": 0.05, "power": 0.8, "max_trials": 30}
"""``--trials``'s flags: None when not given, so one given without ``--trials`` is named."""


def _positive_list(text: str) -> tuple[int, ...]:
    """An argparse type: ``4,8,16``, sorted, each once."""
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        values = []
    if not values or any(v < 1 for v in values):
        raise argparse.ArgumentTypeError(
            f"expected a comma-separated list of positive integers, got {text!r}")
    return tuple(sorted(set(values)))


def _fraction(text: str) -> float:
    """An argparse type: a number strictly between 0 and 1."""
    try:
        v = float(text)
    except ValueError:
        v = -1.0
    if not 0.0 < v < 1.0:
        raise argparse.ArgumentTypeError(f"expected a number between 0 and 1, got {text!r}")
    return v


def _plan_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dirs", nargs="+", metavar="RUN_OR_PROTOCOL_DIR")
    p.add_argument("--robots", type=_positive_list, metavar="N,N,...",
                   help="fleet sizes to plan for, e.g. 4,8,16")
    p.add_argument("--humans", type=_positive_list, metavar="M,M,...",
                   help="numbers of humans to plan for, e.g. 1,2,4")
    p.add_argument("--steps", type=positive, metavar="T",
                   help="steps per planned run (default: the runs' longest)")
    p.add_argument("--replicates", type=positive, default=200, metavar="R",
                   help="posterior draws behind each interval (default 200)")
    p.add_argument("--runs", type=positive, default=1, metavar="K",
                   help="simulated runs averaged per replicate, as a sweep averages its "
                   "seeds (default 1: the interval of one run)")
    p.add_argument("--bin-steps", type=positive, default=25, metavar="S",
                   help="steps per phase of the fitted rates (default 25)")
    p.add_argument("--min-gain", type=_fraction, default=0.05, metavar="F",
                   help="an added human pays while it adds at least this share of "
                   "successes (default 0.05) and ROHE does not fall")
    p.add_argument("--on-site", type=int, metavar="K", dest="on_site",
                   help="of each planned number of humans, how many are on site (the "
                   "rest remote: teleop only, no hard resets; default: the places of "
                   "the runs' people)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", metavar="DIR", help="where to write plan.md, plan.csv and the "
                   "figures (default: first dir)")
    p.add_argument("--against", nargs="+", metavar="DIR",
                   help="measured runs (a sweep of the planned points) to put beside the "
                   "predictions: plan.md's last table and plan-check.csv")
    g = p.add_argument_group("trials a comparison needs (--trials)")
    g.add_argument("--trials", action="store_true",
                   help="instead: from a pilot protocol, the trials each comparison needs")
    g.add_argument("--reference", metavar="ALGORITHM",
                   help="what the others are compared with (default: as testbed report)")
    g.add_argument("--metric", choices=TRIALS_METRICS, help="default rohe")
    g.add_argument("--alpha", type=_fraction, help="default 0.05")
    g.add_argument("--power", type=_fraction, help="default 0.8")
    g.add_argument("--max-trials", type=positive, metavar="K", help="default 30")


def cmd_plan(args: argparse.Namespace) -> int:
    dirs = [Path(d) for d in args.dirs]
    for d in dirs:
        if not d.is_dir():
            raise ConfigError(f"RUN_OR_PROTOCOL_DIR: no such folder {str(d)!r}")
    trial_flags = ["reference", *TRIALS_DEFAULTS]
    if args.trials:
        if args.against:
            raise ConfigError("--against: only without --trials (it checks a plan of "
                              "--robots x --humans)")
        return _plan_trials(args, dirs)
    for name in trial_flags:
        if getattr(args, name) is not None:
            raise ConfigError(f"--{name.replace('_', '-')}: only with --trials")
    for flag in ("robots", "humans"):
        if getattr(args, flag) is None:
            raise ConfigError(f"--{flag}: required (a comma-separated list of positive "
                              "integers, e.g. --robots 4,8,16 --humans 1,2,4), or give --trials")
    if args.out is not None:
        check_out_dir("--out", args.out)
    from testbed.planning.plan import PlanOptions, write_plan

    if args.on_site is not None and args.on_site < 1:
        raise ConfigError(f"--on-site: {args.on_site}; at least 1 (a hard reset needs a "
                          "person in the room with the arms)")
    options = PlanOptions(args.robots, args.humans, args.steps, args.replicates, args.runs,
                          args.bin_steps, args.min_gain, args.seed, on_site=args.on_site)
    against = [Path(d) for d in args.against or []]
    for d in against:
        if not d.is_dir():
            raise ConfigError(f"--against: no such folder {str(d)!r}")
    plan = write_plan(dirs, options, Path(args.out) if args.out else dirs[0])
    if against:
        from testbed.planning.plan_check import write_checks

        plan = write_checks(plan, against, options)
    print(plan.markdown)
    print("plan: " + ", ".join(str(f) for f in plan.files))
    return 0


def _plan_trials(args: argparse.Namespace, dirs: list[Path]) -> int:
    """``--trials``: the trials planner (issue 31's second part), when this build has it."""
    try:
        from testbed.planning.plan_trials import plan_trials
    except ModuleNotFoundError as exc:
        if exc.name != "testbed.planning.plan_trials":
            raise
        raise ConfigError("--trials: this build has no trials planner yet "
                          "(testbed.planning.plan_trials)") from None
    given = {k: getattr(args, k) for k in TRIALS_DEFAULTS}
    opts = {k: TRIALS_DEFAULTS[k] if v is None else v for k, v in given.items()}
    print(plan_trials(dirs, reference=args.reference, metric=str(opts["metric"]),
                      alpha=float(opts["alpha"]), power=float(opts["power"]),
                      max_trials=int(opts["max_trials"])))
    return 0


PLAN = Verb(
    "plan", help="how many people for how many arms (or, --trials, how many trials)",
    description="From finished runs or protocols: fit per algorithm how often arms ask "
    "for a teleop or a reset and how long each human takes, then replay Algorithm 1 for "
    "every N x M point: utilisation, wait, idle time, hard resets, human actions, "
    "successes and ROHE with intervals; plan.md, plan.csv, plan-<algorithm>.png (the "
    "paper's figure 7), where one more human stops paying, and one more person or two "
    "more arms. With --trials: the trials each comparison against the reference needs.",
    add_arguments=_plan_arguments, run=cmd_plan)
