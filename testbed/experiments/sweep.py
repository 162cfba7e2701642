"""Sweeps: a grid over config fields x seeds, run to the end, reported as the paper's
figures 6-9 (appendix 8.4).

A sweep file (``protocols/sweeps/*.toml``) is a protocol-like file: a ``[fleet]``
table (the base fleet), the ``algorithm``, ``steps`` and ``seeds``, and a ``[grid]``
table whose keys are config fields as dotted paths into the fleet (``humans.count``,
``algorithm.t_T``, ``algorithm.t_R``, ``learning.batch_size`` ...) or ``algorithm``
itself (the paper's ablations: ``["cur", "cur-i", "c", "u", "cu"]``), each with its
list of values::

    name = "humans"
    algorithm = "cur"
    steps = 250
    seeds = [0, 1]
    [grid]
    "humans.count" = [1, 2, 3, 4]
    [fleet]
    ...

The grid expands to every combination (``Sweep.points()``, in the file's order) x
every seed; each is one run ``<out>/<point>-s<seed>`` (``humans.count-2-s0``) whose
run.json ``sweep`` names its point, so ``testbed report`` groups the runs by point:
one line per value in each panel (cumulative successes, hard resets, idle time, human
actions, ROHE over timesteps), shading one standard deviation over the seeds. Runs
that finished are skipped and one that died is resumed, as in a protocol. Every value
is validated up front: a bad field or value exits 2 naming it. ``policy`` (a learner
checkpoint, e.g. ``<run>/learner-start.pt``) starts every run from it instead of
pretraining a theta_0 per fleet: a sweep of fleet sizes that holds the policy.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from testbed.core.config import ConfigError, _one_line, read_toml, validation_context
from testbed.experiments.fleet_config import FleetConfig
from testbed.experiments.sweep_point import ALGORITHM_KEY, SweepPoint
from testbed.fleet.algorithms import ALGORITHM_NAMES

if TYPE_CHECKING:
    from testbed.experiments.hooks import TrialHooks
    from testbed.results.report import Report

class Sweep(BaseModel):
    # defer_build: its fleet's hosts are a union of the installed backends (core/host_config.py)
    model_config = ConfigDict(extra="forbid", frozen=True, defer_build=True)

    name: str
    algorithm: str = "cur"
    steps: int = Field(250, ge=1)
    seeds: list[int] = Field(default_factory=lambda: [0, 1], min_length=1)
    out: str | None = None
    """Default ``runs/sweep-<name>``."""
    humans: Literal["scripted", "gui", "web"] = "scripted"
    grid: dict[str, list[Any]] = Field(min_length=1)
    fleet: FleetConfig = Field(default_factory=FleetConfig)
    policy: str | None = None
    """Every run starts from this learner checkpoint (``testbed trial --policy``), e.g. a
    protocol's theta_0 (``<run>/learner-start.pt``, its data included) instead of
    pretraining one per fleet: a sweep of fleet sizes that holds the policy (and the
    thresholds resolved on its data) fixed, as ``testbed plan`` assumes."""

    @model_validator(mode="after")
    def _check(self) -> Sweep:
        for a in [self.algorithm, *self.grid.get(ALGORITHM_KEY, [])]:
            if a not in ALGORITHM_NAMES:
                raise ValueError(f"unknown algorithm {a!r}; use {', '.join(ALGORITHM_NAMES)}")
        for key, values in self.grid.items():
            if not values:
                raise ValueError(f"grid.{key}: give at least one value")
        return self

    @property
    def folder(self) -> Path:
        return Path(self.out or f"runs/sweep-{self.name}")

    def points(self) -> list[SweepPoint]:
        """Every combination of the grid's values, the first key varying slowest."""
        keys = list(self.grid)
        return [SweepPoint(dict(zip(keys, combo, strict=True)))
                for combo in itertools.product(*(self.grid[k] for k in keys))]

    def runs(self) -> list[SweepRun]:
        """Every (point, seed): its run name, algorithm and fleet config."""
        return [SweepRun(f"{p.label}-s{seed}", p, seed, p.algorithm(self.algorithm),
                         p.apply(self.fleet)) for p in self.points() for seed in self.seeds]


@dataclass(frozen=True)
class SweepRun:
    name: str
    point: SweepPoint
    seed: int
    algorithm: str
    fleet: FleetConfig


def load_sweep(path: Path) -> Sweep:
    """A sweep file, every grid point validated (ConfigError: one line naming the field)."""
    data = read_toml(path, "sweep")
    if "grid" not in data:
        raise ConfigError(f"{path}: grid: a sweep file needs a [grid] table of config "
                          "fields and their values")
    try:
        sweep = Sweep.model_validate(data, context=validation_context(True))
    except ValidationError as err:
        raise ConfigError(_one_line(err, str(path))) from None
    try:
        sweep.runs()
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from None
    if sweep.policy is not None and not Path(sweep.policy).is_file():
        raise ConfigError(f"{path}: policy: no such file {sweep.policy!r}; give a learner.pt "
                          "(a run's learner-start.pt is its theta_0)")
    return sweep


def pretrain_critics_of(sweep: Sweep) -> list[str]:
    """theta_0's critics: every one any of the grid's algorithms reads (one per fleet)."""
    from testbed.experiments.protocol import pretrain_critics

    return pretrain_critics(sorted({r.algorithm for r in sweep.runs()}))


def run_sweep_run(sweep: Sweep, folder: Path, index: int, *,
                  meta: dict[str, Any] | None = None,
                  hooks: TrialHooks | None = None) -> dict[str, Any]:
    """Run ``sweep.runs()[index]`` in ``folder`` (``run_named``: skipped when finished,
    resumed when checkpointed); ``meta``: extra run.json keys; ``hooks``: as a
    protocol's. The serial loop and a Ray task both call this."""
    from testbed.experiments.protocol import run_named
    from testbed.experiments.trial import TrialOptions

    run = sweep.runs()[index]
    opts = TrialOptions(algorithm=run.algorithm, steps=sweep.steps, seed=run.seed,
                        out=str(folder), humans=sweep.humans, name=run.name,
                        pretrain_critics=pretrain_critics_of(sweep), policy=sweep.policy)
    # "index": the point's place in the grid, so the report lists points in the grid's
    # order (1, 3, 5, 10, 20), not their names' (1, 10, 20, 3, 5)
    run_meta = {**(meta or {}), "sweep": {"name": sweep.name, "point": run.point.label,
                                          "index": index // len(sweep.seeds),
                                          "values": run.point.values, "seed": run.seed}}
    return run_named(run.fleet, opts, folder, meta=run_meta, hooks=hooks)


def run_sweep(sweep: Sweep, out: str | None = None, *,
              hooks: TrialHooks | None = None) -> Report:
    """Run every (point, seed) not finished yet, then the report (figure: curves.png)."""
    from testbed.results.report import write_report

    folder = Path(out) if out is not None else sweep.folder
    folder.mkdir(parents=True, exist_ok=True)
    for index in range(len(sweep.runs())):
        run_sweep_run(sweep, folder, index, hooks=hooks)
    return write_report([folder], folder)
