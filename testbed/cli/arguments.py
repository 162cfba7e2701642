"""What a verb is, and the arguments several verbs share.

A ``Verb`` holds everything about one verb of ``testbed`` side by side: its name, its
help line and description, the function that adds its arguments and the handler that
runs it; ``testbed.cli.verbs`` lists them and ``build_parser`` loops over that list, so
adding a verb, or an argument to one, is an edit in one place. The helpers here are the
arguments more than one verb takes (``--config``, the trial's, the fan-out's).

This module is imported for ``testbed --help``: it imports nothing but argparse.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass

ALGORITHM_HELP = ("bc, random, fleet-ed, fleet-td, cur, monitor, cur-i and the ablations c, u, "
                  "r, cu, cr, ur, uc, ru, cru (default: config)")
"""``--algorithm``'s help: every name of ``testbed.fleet.algorithms.ALGORITHMS`` (the one
home of the list; written out here so ``--help`` imports nothing, and held to the
registry by ``tests/test_architecture.py::test_every_list_of_the_algorithms_is_the_registrys``)."""
HUMANS = ["scripted", "gui", "web"]
"""The choices of every ``--humans``: the twin's scripted expert, the OpenCV console,
the browser console."""


@dataclass(frozen=True)
class Verb:
    """One verb: ``add_arguments`` fills its subparser, ``run`` does the work and returns
    the exit status (0 done, 1 failed); a bad config or argument raises ``ConfigError``."""

    name: str
    help: str
    description: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


def positive(text: str) -> int:
    """An argparse type: an integer >= 1."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be >= 1")
    return v


def add_config(p: argparse.ArgumentParser) -> None:
    """``--config``: the fleet the verb works on."""
    p.add_argument("--config", metavar="FILE", help="fleet config (TOML), or a protocol file "
                   "(its [fleet] is used); default: the built-in twin fleet")


def add_trial_arguments(p: argparse.ArgumentParser) -> None:
    """What one trial is run with: ``--config`` and the config's trial fields overridden."""
    add_config(p)
    p.add_argument("--algorithm", metavar="NAME", help=ALGORITHM_HELP)
    p.add_argument("--steps", type=positive, metavar="T", help="timesteps (default: config)")
    p.add_argument("--seed", type=int, metavar="S", help="trial seed (default: config)")
    p.add_argument("--out", metavar="DIR", help="folder of runs (default: config, runs/)")
    p.add_argument("--humans", choices=HUMANS,
                   help="who helps: scripted (twin), gui (the OpenCV console), web (the "
                   "browser console, [humans.web] of the config) (default: config)")
    p.add_argument("--policy", metavar="FILE", help="start from this trained learner.pt "
                   "instead of pretraining")
    p.add_argument("--name", help="run folder name (default: ALGORITHM-sSEED)")


def add_dry_run(p: argparse.ArgumentParser) -> None:
    """``--dry-run``: print what would be done and how long it would take, then stop."""
    p.add_argument("--dry-run", action="store_true",
                   help="print the plan (each phase before step 1, the steps, how long "
                   "each takes) and exit: no arm moves, no folder is made")


def add_fanout_arguments(p: argparse.ArgumentParser) -> None:
    """Where many trials run: here one after another (default), or as Ray tasks."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=positive, metavar="N",
                   help="run the trials on a local Ray with N CPUs (twin fleets only; "
                   'needs the "ray" extra)')
    g.add_argument("--ray", metavar="ADDRESS",
                   help="run the trials on the Ray cluster at ADDRESS; the output folder "
                   "must be on storage every worker sees")
    p.add_argument("--cpus-per-trial", type=positive, default=1, metavar="C",
                   help="with --workers/--ray: CPUs (and torch threads) per trial")
