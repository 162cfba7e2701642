"""The whole fleet's config (``FleetConfig``) and the loaders every verb reads it with.

Why here, in experiments: the fleet composes every room's section (the humans', the
algorithm's, learning's, the hosts' union of every installed backend's model), so it
lives above them all; the rooms below read only their own section. ``load_config`` is
the only way a config enters the program; ``default_twin_config`` is the built-in
2 x 2-arm twin fleet that ``testbed trial`` runs with no ``--config``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import Field, model_validator

from testbed.core.config import ConfigError, Name, StrictModel, parse_model, read_toml
from testbed.core.host_config import AnyHost, default_hosts
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.learning.learning_config import LearningConfig
from testbed.monitor.monitor_config import MonitorConfig
from testbed.people.people_config import HumansConfig

__all__ = ["PROTOCOL_KEYS", "TWIN_U_HAT", "FleetConfig", "TrialConfig", "default_twin_config",
           "file_kind", "load_config", "load_fleet", "parse_config", "require_protocol"]


class TrialConfig(StrictModel):
    steps: int = Field(250, ge=1, le=1_000_000)
    seed: int = 0
    out: str = "runs"


class FleetConfig(StrictModel):
    name: Name = "twin"
    trial: TrialConfig = TrialConfig()
    humans: HumansConfig = HumansConfig()
    algorithm: AlgorithmConfig = AlgorithmConfig()
    learning: LearningConfig = LearningConfig()
    monitor: MonitorConfig = MonitorConfig()
    hosts: list[AnyHost] = Field(default_factory=default_hosts)

    @model_validator(mode="after")
    def _unique_hosts(self) -> FleetConfig:
        names = [h.name for h in self.hosts]
        if len(set(names)) != len(names):
            raise ValueError("host names must be unique")
        if not self.hosts:
            raise ValueError("a fleet needs at least one host")
        return self

    @property
    def robot_names(self) -> list[str]:
        return [f"{h.name}/{a.name}" for h in self.hosts for a in h.arms]


def parse_config(data: dict[str, Any], source: str = "config", *,
                 check_files: bool = True, prefix: tuple[str, ...] = ()) -> FleetConfig:
    """Validate a dict into a FleetConfig, or raise ConfigError with one line.

    ``prefix``: where the dict sits in its file (``("fleet",)`` for a protocol's fleet),
    so the error names the field as the file spells it.
    """
    return parse_model(FleetConfig, data, source, check_files=check_files, prefix=prefix)


PROTOCOL_KEYS = ("algorithms", "trials")


def file_kind(data: dict[str, Any]) -> Literal["fleet", "protocol"]:
    """A protocol has top-level ``algorithms``/``trials`` or a ``[fleet]`` table; anything
    else is read as a fleet config (and validated as one)."""
    if isinstance(data.get("fleet"), dict) or any(k in data for k in PROTOCOL_KEYS):
        return "protocol"
    return "fleet"


def require_protocol(data: dict[str, Any], path: str | Path) -> None:
    """Name a fleet config given where a protocol is expected, in one line."""
    if file_kind(data) == "fleet":
        raise ConfigError(
            f"{path} is a fleet config, not a protocol: run it with `testbed trial --config "
            f"{path}`, or give a protocol file (top-level algorithms and trials, its fleet "
            "in a [fleet] table)")


def load_fleet(path: str | Path | None, *, check_files: bool = True) -> FleetConfig:
    """The fleet of a fleet config or of a protocol file (its ``[fleet]`` table).

    Every verb that takes a fleet reads it here, so ``testbed check --config
    protocols/physical.toml`` checks the protocol's own hosts. ``None`` gives the
    built-in twin fleet.
    """
    if path is None:
        return default_twin_config()
    data = read_toml(path)
    if file_kind(data) == "protocol":
        fleet = data.get("fleet", {})
        if not isinstance(fleet, dict):
            raise ConfigError(f"{path}: fleet: a protocol's fleet must be a [fleet] table")
        return parse_config(fleet, str(path), check_files=check_files, prefix=("fleet",))
    return parse_config(data, str(path), check_files=check_files)


def load_config(path: str | Path | None) -> FleetConfig:
    """Read and validate a fleet config (or a protocol's fleet): ``load_fleet``."""
    return load_fleet(path)


TWIN_U_HAT = 0.17
"""The twin's uncertainty threshold: the 75th percentile of its ensemble's uncertainty
in C.U.R. runs (the paper's 0.05 made 55% of the twin's arm-steps eligible)."""


def default_twin_config() -> FleetConfig:
    """2 twin hosts x 2 arms, 2 scripted humans, local transport, 250 steps, C.U.R.

    Pretraining is sized for README command 1's 10-minute target (setup, pretraining
    and the 250-step trial at the paper's batch 256, on a 2-core machine): 60 policy +
    60 critic steps (~2 min; the trial's training steps are the rest). 120 steps
    evaluated no better within the noise of ``testbed evaluate`` (docs/notes/fleet.md,
    issue 13); the paper-scale pretraining lives in ``protocols/*.toml``. u_hat is the
    twin's 0.17: the 75th percentile of the uncertainty in C.U.R. runs, measured before
    quantile thresholds existed (the protocols now give ``"q0.75"``).
    """
    return FleetConfig(algorithm=AlgorithmConfig(u_hat=TWIN_U_HAT),
                       learning=LearningConfig(pretrain_steps=60, critic_transitions=400))
