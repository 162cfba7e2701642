"""What each ``testbed`` verb does, given its parsed arguments.

Kept apart from ``cli.py`` so that ``testbed --help`` imports nothing heavy; these
functions import drivers, torch and the console only when a verb needs them.
"""

from __future__ import annotations

import argparse
import json
import re
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rich.console import Console

from testbed.core.config import NAME_PATTERN, ConfigError, FleetConfig, load_fleet
from testbed.experiments.progress import TrialProgress
from testbed.experiments.trial import TrialOptions, run_trial
from testbed.fleet.algorithms import ALGORITHM_NAMES

console = Console(stderr=True)


def _config(args: argparse.Namespace) -> FleetConfig:
    """The fleet of ``--config``: a fleet config or a protocol file's ``[fleet]``."""
    return load_fleet(getattr(args, "config", None))


# ---- checks of what the user asked for, before anything starts (exit 2, one line) ----
def check_device(cfg: FleetConfig) -> None:
    """``learning.device = "cuda"`` needs CUDA here. Only verbs that train or run a
    policy call this, so torch is imported then, not when the config is read."""
    if cfg.learning.device != "cuda":
        return
    import torch

    if not torch.cuda.is_available():
        raise ConfigError('learning.device: "cuda" but torch sees no CUDA device on this '
                          'machine; set it to "auto" (CUDA when present) or "cpu"')


WEB_EXTRA = ("starlette", "uvicorn", "websockets")
"""The modules of pyproject's ``web`` extra (``--humans web``): checked before anything
starts, so a missing one is one line, not an ImportError after pretraining."""


def check_humans(kind: str, cfg: FleetConfig, *, teleop: bool = True) -> None:
    """The humans can work here: the console can open its windows (``gui``), the browser
    console has someone to serve (``web``; its address, port, tokens and TLS files are
    checked with the config), or the scripted expert has a twin to read its pushes from
    (``scripted`` with ``teleop``).

    A yumi host whose controller is the hardware twin (``twin+http://``) has one: a
    rehearsal's scripted humans read it over the twin's side channel.
    """
    where = "--humans (or humans.kind)"
    if kind == "gui":
        if cfg.humans.count < 1:
            raise ConfigError("humans.count: the operator console needs at least one person; "
                              "set humans.count >= 1")
        from gui.display import check_window_system, default_display
        from gui.errors import ConsoleUnavailable

        try:
            check_window_system([default_display()] * cfg.humans.count)
        except ConsoleUnavailable as exc:
            raise ConfigError(f"{where} gui: {exc}") from None
    elif kind == "web":
        if cfg.humans.count < 1:
            raise ConfigError("humans.count: the browser console needs at least one person; "
                              "set humans.count >= 1")
        import importlib.util

        missing = [m for m in WEB_EXTRA if importlib.util.find_spec(m) is None]
        if missing:
            raise ConfigError(f"{where} web: the browser console needs the web extra "
                              f"({', '.join(missing)} not installed); pip install -e "
                              '".[web]"')
    elif kind == "scripted" and teleop:
        real = [h.name for h in cfg.hosts if h.backend != "twin"
                and not str(getattr(h, "controller_url", "")).startswith("twin+")]
        if real:
            raise ConfigError(f"{where} scripted: scripted humans teleoperate from the twin's "
                              f"expert and host {real[0]} is a physical robot; use --humans gui "
                              "(or web)")


def check_policy(path: str, cfg: FleetConfig) -> None:
    """``--policy`` is a learner checkpoint this config can load (same ensemble size and
    augmentation factor): found now, not after the hosts have started."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"--policy: no such file {path!r}; give a learner.pt")
    from testbed.learning import checkpoint

    try:
        saved = checkpoint.load(p)["cfg"]
    except Exception as exc:  # torch's many ways of saying "not a checkpoint"
        why = " ".join(str(exc).split())[:160]
        raise ConfigError(f"--policy: {path} is not a learner checkpoint ({why}); give the "
                          "learner.pt of a trial or of testbed pretrain") from None
    for field in ("ensemble_size", "augmentation_factor"):
        if saved.get(field) != getattr(cfg.learning, field):
            raise ConfigError(f"--policy: {path} has learning.{field} = {saved.get(field)}, "
                              f"the config {getattr(cfg.learning, field)}; use the "
                              "checkpoint's value in the config")


def check_out_dir(flag: str, path: str) -> None:
    """A folder the verb will create or fill: not an existing file."""
    if Path(path).exists() and not Path(path).is_dir():
        raise ConfigError(f"{flag}: {path!r} is a file, not a folder")


def check_out_file(flag: str, path: str) -> None:
    """A file the verb writes at the end: its folder exists now, not after the work."""
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{flag}: {path!r} is a folder; give a file name")
    if not p.parent.is_dir():
        raise ConfigError(f"{flag}: no such folder {str(p.parent)!r}; create it first")


def check_name(name: str | None) -> None:
    if name is not None and not re.fullmatch(NAME_PATTERN, name):
        raise ConfigError(f"--name: {name!r} is not a run folder name (letters, digits, "
                          "_ . -; not starting with . or -)")


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
    if opts.algorithm == "random" and cfg.algorithm.budget_match is not None:
        raise ConfigError(f"algorithm.random_budget = {cfg.algorithm.random_budget!r} is "
                          "resolved by a protocol (from the matched run of the same trial); "
                          "give a number in [0, 1] for a trial alone")
    check_name(opts.name)
    check_out_dir("--out (or trial.out)", opts.out)
    check_device(cfg)
    check_humans(opts.humans, cfg, teleop=not opts.evaluate)
    if opts.policy is not None:
        check_policy(opts.policy, cfg)
    return opts


def resume_options(resume: Path) -> tuple[FleetConfig, TrialOptions]:
    """The config and options of a run to resume, checked as a new trial's are."""
    from testbed.records.run_dir import RunDir

    if not resume.is_dir():
        raise ConfigError(f"--resume: no such run folder {str(resume)!r}")
    run = RunDir(resume)
    cfg = run.read_config()
    options = run.read_meta().get("options")
    if not isinstance(options, dict):
        raise ConfigError(f"--resume: {resume} has no run.json with the trial's options; "
                          "not a trial run folder")
    try:
        opts = TrialOptions(**options)
    except TypeError as exc:
        raise ConfigError(f"--resume: {resume}/run.json: unexpected options ({exc})") from None
    if not run.state.exists():
        raise ConfigError(f"--resume: {resume}: no checkpoint yet (state.json); start a new "
                          "trial")
    check_device(cfg)
    check_humans(opts.humans, cfg, teleop=not opts.evaluate)
    return cfg, opts


def print_summary(run_dir: Path, summary: dict[str, Any]) -> None:
    print(f"run: {run_dir}")
    print(json.dumps(summary, indent=2))


def cmd_trial(args: argparse.Namespace) -> int:
    if args.resume:
        resume = Path(args.resume)
        cfg, opts = resume_options(resume)
    else:
        resume = None
        cfg = _config(args)
        opts = trial_options(cfg, args)
    with TrialProgress(opts.steps, cfg.humans.count, len(cfg.robot_names)) as bar:
        run, summary = run_trial(cfg, opts, resume=resume, hooks=bar)
    print_summary(run.path, summary)
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    cfg = _config(args)
    args.algorithm = "bc"  # C-prioritised hard resets, no teleop, no learning (seed 8.3.4)
    opts = trial_options(cfg, args, evaluate=True)
    from testbed.records.run_dir import evaluated, evaluation_label

    source = evaluated(Path(args.policy))
    opts.name = args.name or f"eval-{Path(args.policy).parent.name or 'policy'}-s{opts.seed}"
    # the report's row: never the allocation's "bc", but what was evaluated
    opts.label = evaluation_label(source["algorithm"])
    with TrialProgress(opts.steps, cfg.humans.count, len(cfg.robot_names)) as bar:
        run, summary = run_trial(cfg, opts, hooks=bar, meta={"evaluates": source})
    print_summary(run.path, summary)
    return 0


def cmd_protocol(args: argparse.Namespace) -> int:
    from testbed.experiments.protocol import load_protocol, run_protocol

    proto = load_protocol(Path(args.file))
    if args.out is not None:
        check_out_dir("--out", args.out)
    check_device(proto.fleet)
    check_humans(proto.humans, proto.fleet)
    if args.workers is not None or args.ray is not None:
        from testbed.experiments.fanout import run_protocol_on_ray
        from testbed.experiments.report import write_report

        folder = Path(args.out or proto.out)
        run_protocol_on_ray(proto, folder, address=args.ray, workers=args.workers,
                            cpus_per_trial=args.cpus_per_trial)
        report = write_report([folder], folder)
    else:
        report = run_protocol(proto, out=args.out, ask=not args.yes)
    print(report.markdown)
    print(f"report: {report.folder}")
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    from testbed.experiments.sweep import load_sweep, run_sweep

    sweep = load_sweep(Path(args.file))
    if args.out is not None:
        check_out_dir("--out", args.out)
    for run in sweep.runs():
        check_device(run.fleet)
        check_humans(sweep.humans, run.fleet)
    if args.workers is not None or args.ray is not None:
        from testbed.experiments.fanout import run_sweep_on_ray

        run_sweep_on_ray(sweep, Path(args.out) if args.out else sweep.folder,
                         address=args.ray, workers=args.workers,
                         cpus_per_trial=args.cpus_per_trial)
    report = run_sweep(sweep, out=args.out)  # every run finished: skipped, then the report
    print(report.markdown)
    print(f"report: {report.folder} (figure: curves.png)")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from testbed.experiments.report import write_report

    dirs = [Path(d) for d in args.dirs]
    for d in dirs:
        if not d.is_dir():
            raise ConfigError(f"RUN_OR_PROTOCOL_DIR: no such folder {str(d)!r}")
    if args.out is not None:
        check_out_dir("--out", args.out)
    report = write_report(dirs, Path(args.out) if args.out else dirs[0])
    print(report.markdown)
    print(f"report: {report.folder}")
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    from testbed.lab.preflight import preflight

    cfg = _config(args)
    check_out_file("--mosaic", args.mosaic)
    ok = preflight(cfg, Path(args.mosaic), print_line=print)
    return 0 if ok else 1


def cmd_collect(args: argparse.Namespace) -> int:
    from testbed.experiments.build import build_hosts, make_humans
    from testbed.experiments.pretraining import collect_demos, save_transitions

    cfg = _config(args)
    count = args.count or cfg.learning.demos
    check_out_file("--out", args.out)
    check_humans(args.humans or cfg.humans.kind, cfg)
    humans = make_humans(args.humans or cfg.humans.kind, cfg.humans.count, cfg.humans.web)
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


def _with_pretrain_steps(cfg: FleetConfig, steps: int | None) -> FleetConfig:
    """``--steps`` of ``testbed pretrain`` / ``train``: both phases take that many."""
    if steps is None:
        return cfg
    if steps < 0:
        raise ConfigError("--steps: must be >= 0")
    return cfg.model_copy(update={"learning": cfg.learning.model_copy(
        update={"pretrain_steps": steps, "critic_pretrain_steps": None})})


def cmd_pretrain(args: argparse.Namespace) -> int:
    from testbed.experiments.build import build_hosts, make_humans
    from testbed.experiments.learners import PRETRAIN_SEED, new_learner
    from testbed.experiments.pretraining import load_transitions, pretrain

    cfg = _with_pretrain_steps(_config(args), args.steps)
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
    humans = make_humans(args.humans or cfg.humans.kind, cfg.humans.count, cfg.humans.web)
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


def cmd_calibrate(args: argparse.Namespace) -> int:
    from testbed.lab.calibrate import cmd_calibrate as calibrate  # cv2, only when asked

    return calibrate(args)


def cmd_rehearse(args: argparse.Namespace) -> int:
    from testbed.experiments.protocol import load_protocol
    from testbed.lab.rehearsal import RehearsalError, RehearsalOptions, rehearse, require_yumi

    path = Path(args.protocol)
    proto = load_protocol(path, check_files=False)  # the lab's key files need not exist here
    require_yumi(proto.fleet)
    algorithms = [a for a in (args.algorithms or "").split(",") if a] or None
    for a in algorithms or []:
        if a not in proto.algorithms:
            raise ConfigError(f"--algorithms: {a!r} is not one of the protocol's "
                              f"{', '.join(proto.algorithms)}")
    check_humans(args.humans, proto.fleet, teleop=False)
    check_device(proto.fleet)
    if args.realtime < 0:
        raise ConfigError("--realtime: must be >= 0")
    try:
        result = rehearse(RehearsalOptions(path, args.trials, args.steps, args.humans,
                                           args.quick, Path(args.out) if args.out else None,
                                           algorithms, args.realtime))
    except RehearsalError as exc:
        console.print(f"testbed rehearse: {exc}", markup=False, highlight=False)
        return 1
    print(result.report_markdown)
    for robot, fig in result.calibration.items():
        print(f"calibration {robot}: against the twin's true camera model median "
              f"{fig['median_px']:.2f} px / {fig['median_mm']:.2f} mm, max "
              f"{fig['max_px']:.2f} px / {fig['max_mm']:.2f} mm")
    print(f"rehearsal: {result.folder} (one folder per run; report.md, rehearsal.md)")
    return 0


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


def cmd_train(args: argparse.Namespace) -> int:
    from testbed.datasets.dataset_io import load_frames
    from testbed.datasets.sources import DEMO_FIELDS
    from testbed.datasets.training import TrainingData, training_data
    from testbed.experiments.learners import PRETRAIN_SEED, new_learner

    cfg = _with_pretrain_steps(_config(args), args.steps)
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
                         progress=lambda phase, done, total: bar.on_phase(
                             f"train {phase}", done, total))
    learner.save(Path(args.out))
    print(f"{len(data.actions)} labelled frames, {len(transitions)} transitions -> "
          f"learner {args.out}")
    return 0


VERBS: dict[str, Callable[[argparse.Namespace], int]] = {
    "trial": cmd_trial,
    "evaluate": cmd_evaluate,
    "protocol": cmd_protocol,
    "sweep": cmd_sweep,
    "report": cmd_report,
    "check": cmd_check,
    "collect": cmd_collect,
    "pretrain": cmd_pretrain,
    "calibrate": cmd_calibrate,
    "rehearse": cmd_rehearse,
    "export": cmd_export,
    "train": cmd_train,
}
