"""The checks of what the user asked for, made before anything starts.

A bad config or argument must be one line naming the field and the fix (exit 2), found
before a host starts, a folder is made or a minute of pretraining is spent: every verb
calls these first. They raise ``ConfigError``; ``testbed.cli.main`` prints it.

Imported by the verbs' modules, so also for ``testbed --help``: what is heavy (torch,
the console, the trial) is imported inside the check that needs it.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from testbed.core.backend_registry import backend_of
from testbed.core.config import NAME_PATTERN, ConfigError
from testbed.experiments.controller_gate import TrialRefused
from testbed.experiments.fleet_config import FleetConfig, load_fleet

if TYPE_CHECKING:
    from testbed.experiments.trial import TrialOptions


def refused(verb: str, exc: TrialRefused) -> int:
    """A trial the controllers' check refused before step 1 (exit 1: a fault the
    operator must fix, not a bad argument): the one line, then its FAULT lines, on
    stderr."""
    sys.stderr.write(f"testbed {verb}: {exc}\n" + "".join(f"{line}\n" for line in exc.faults))
    return 1


def load_config(args: argparse.Namespace) -> FleetConfig:
    """The fleet of ``--config``: a fleet config or a protocol file's ``[fleet]``. With
    ``--dry-run`` the files it names (keys, known_hosts, calibrations) are not required:
    a plan is printed before the lab is set up (:func:`say_unchecked`)."""
    return load_fleet(getattr(args, "config", None), check_files=not dry_run(args))


def dry_run(args: argparse.Namespace) -> bool:
    """Whether the verb only prints its plan (``--dry-run``): then neither the config's
    files nor the humans' display or web extra are checked, the rest is."""
    return bool(getattr(args, "dry_run", False))


UNCHECKED = ("  --dry-run: not checked: the files the config names (keys, known_hosts, "
             "calibrations, certificates) and the humans' display or web extra; the run "
             "itself checks them")
"""What a plan printed by ``--dry-run`` says it left unchecked (issue: a dry run before
the lab's setup is done)."""


def say_unchecked() -> None:
    """After a ``--dry-run``'s plan: what it did not check."""
    print(UNCHECKED, flush=True)


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


def check_humans(kind: str, cfg: FleetConfig, *, teleop: bool = True,
                 available: bool = True) -> None:
    """The humans can work here: the console can open its windows (``gui``), the browser
    console has someone to serve (``web``; its address, port, tokens and TLS files are
    checked with the config), or the scripted expert has a twin to read its pushes from
    (``scripted`` with ``teleop``).

    A yumi host whose controller is on loopback is a hardware twin (a lab's IRC5 is on
    its own network, never on this machine): a rehearsal's scripted humans read it over
    the twin's side channel. ``available=False`` (a ``--dry-run``): what this machine
    has (a display, the web extra) is not checked, what the config says still is.
    """
    where = "--humans (or humans.kind)"
    if kind == "gui":
        if cfg.humans.count < 1:
            raise ConfigError("humans.count: the operator console needs at least one person; "
                              "set humans.count >= 1")
        if not available:
            return
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
        if not available:
            return
        import importlib.util

        missing = [m for m in WEB_EXTRA if importlib.util.find_spec(m) is None]
        if missing:
            raise ConfigError(f"{where} web: the browser console needs the web extra "
                              f"({', '.join(missing)} not installed); pip install -e "
                              '".[web]"')
    elif kind == "scripted" and teleop:
        real = [h.name for h in cfg.hosts if not backend_of(h).scripted_teleop(h)]
        if real:
            raise ConfigError(f"{where} scripted: scripted humans teleoperate from the twin's "
                              f"expert and host {real[0]} is a physical robot; use --humans gui "
                              "(or web)")


def check_policy(path: str, cfg: FleetConfig, what: str = "--policy") -> None:
    """``--policy`` is a learner checkpoint this config can load (same ensemble size and
    augmentation factor): found now, not after the hosts have started. ``what``: the
    flag or field that named it, for the one-line error."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{what}: no such file {path!r}; give a learner.pt")
    from testbed.learning import checkpoint

    try:
        saved = checkpoint.load(p)["cfg"]
    except Exception as exc:  # torch's many ways of saying "not a checkpoint"
        why = " ".join(str(exc).split())[:160]
        raise ConfigError(f"{what}: {path} is not a learner checkpoint ({why}); give the "
                          "learner.pt of a trial or of testbed pretrain") from None
    for field in ("ensemble_size", "augmentation_factor"):
        if saved.get(field) != getattr(cfg.learning, field):
            raise ConfigError(f"{what}: {path} has learning.{field} = {saved.get(field)}, "
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
    """``--name``: a run folder name, never a path out of the folder of runs."""
    if name is not None and not re.fullmatch(NAME_PATTERN, name):
        raise ConfigError(f"--name: {name!r} is not a run folder name (letters, digits, "
                          "_ . -; not starting with . or -)")


def check_algorithm(name: str) -> None:
    """``--algorithm`` (or the config's): one the fleet knows."""
    from testbed.fleet.algorithms import ALGORITHM_NAMES

    if name not in ALGORITHM_NAMES:
        raise ConfigError(
            f"--algorithm (or algorithm.name): unknown algorithm {name!r}; "
            f"use one of {', '.join(ALGORITHM_NAMES)}"
        )


def trial_options(cfg: FleetConfig, args: argparse.Namespace, **over: Any) -> TrialOptions:
    """The options of a new trial (the arguments over the config, then ``over``), every
    one checked."""
    from testbed.experiments.trial import TrialOptions

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
    check_algorithm(opts.algorithm)
    if opts.algorithm == "random" and cfg.algorithm.budget_match is not None:
        raise ConfigError(f"algorithm.random_budget = {cfg.algorithm.random_budget!r} is "
                          "resolved by a protocol (from the matched run of the same trial); "
                          "give a number in [0, 1] for a trial alone")
    check_name(opts.name)
    check_out_dir("--out (or trial.out)", opts.out)
    check_device(cfg)
    check_humans(opts.humans, cfg, teleop=not opts.evaluate, available=not dry_run(args))
    if opts.policy is not None:
        check_policy(opts.policy, cfg)
    return opts


def resume_options(resume: Path) -> tuple[FleetConfig, TrialOptions]:
    """The config and options of a run to resume, checked as a new trial's are."""
    from testbed.experiments.trial import TrialOptions
    from testbed.records.run_dir import RunDir

    if not resume.is_dir():
        raise ConfigError(f"--resume: no such run folder {str(resume)!r}")
    run = RunDir(resume)
    cfg = run.read_config(FleetConfig)
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
    check_store_appendable(resume)
    check_device(cfg)
    check_humans(opts.humans, cfg, teleop=not opts.evaluate)
    return cfg, opts


def check_store_appendable(resume: Path) -> None:
    """A run whose data store has another frame layout (written by a build of another
    format) is refused before anything starts: resuming would append frames of this
    build's size under the stored dtype."""
    from testbed.records import store

    folder = resume / store.FOLDER
    if not (folder / store.META).exists():
        return
    try:
        store.check_appendable(folder, store.read_meta(folder))
    except store.RunDataError as exc:
        raise ConfigError(f"--resume: {exc}") from None


def with_pretrain_steps(cfg: FleetConfig, steps: int | None) -> FleetConfig:
    """``--steps`` of ``testbed pretrain`` / ``train``: both phases take that many."""
    if steps is None:
        return cfg
    if steps < 0:
        raise ConfigError("--steps: must be >= 0")
    return cfg.model_copy(update={"learning": cfg.learning.model_copy(
        update={"pretrain_steps": steps, "critic_pretrain_steps": None})})
