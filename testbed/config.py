"""The fleet configuration: a TOML file validated by pydantic, unknown keys rejected.

Why pydantic: it gives typed, nested validation with the failing field's path for free,
so every bad config becomes one line that names the field (DESIGN.md section 8) instead
of a traceback deep inside a driver. ``load_config`` is the only way a config enters
the program; ``default_twin_config`` is the built-in 2 x 2-arm twin fleet that
``testbed trial`` runs with no ``--config``.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]*$"
Name = Annotated[str, Field(pattern=NAME_PATTERN, max_length=64)]


class ConfigError(ValueError):
    """A config or argument that cannot be used; ``str()`` is the one line to print."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ArmConfig(_Strict):
    name: Name
    crop: tuple[int, int, int, int] | None = None
    """Pixel box (x0, y0, x1, y1) of this arm's workspace in the host camera image."""
    mirror: bool = False
    """Mirror the crop left-right into the canonical frame (the right arm)."""
    calibration: str | None = None
    """Path (on the host) of the image-to-table homography file (YuMi backend)."""

    @model_validator(mode="after")
    def _crop_is_a_box(self) -> ArmConfig:
        if self.crop is not None:
            x0, y0, x1, y1 = self.crop
            if min(self.crop) < 0 or x1 <= x0 or y1 <= y0:
                raise ValueError("crop must be (x0, y0, x1, y1) with 0 <= x0 < x1, 0 <= y0 < y1")
        return self


class HostConfig(_Strict):
    name: Name
    backend: Literal["twin", "yumi"] = "twin"
    transport: Literal["local", "ssh"] = "local"
    address: str = "127.0.0.1"
    port: int = Field(22, ge=1, le=65535)
    user: str | None = None
    key_file: str | None = None
    known_hosts: str | None = None
    python: str = "python3"
    """Interpreter that runs the agent; over SSH it must be an absolute path."""
    workdir: str | None = None
    """Project checkout on the host (over SSH); the agent runs with it as PYTHONPATH."""
    seed: int | None = None
    """Twin only: the cell's world seed (default: derived from the trial seed)."""
    camera: str | None = None
    """YuMi only: camera device index or a video file path for VideoCapture."""
    controller_url: str | None = None
    """YuMi only: the Robot Web Services address of the IRB 14000 controller."""
    deadline_s: float = Field(10.0, gt=0, le=600)
    """Per-call deadline for a push or an observation on this host."""
    heartbeat_s: float = Field(2.0, gt=0, le=600)
    """Idle time after which the controller checks the agent is alive (application
    heartbeat: SSH keepalives do not notice a dead peer)."""
    connect_timeout_s: float = Field(20.0, gt=0, le=600)
    """Budget to (re)connect: SSH handshake, agent start, backend start, hello."""
    physics: bool = True
    """Twin only: False runs the agent's no-physics mode (canned images; benchmarks)."""
    arms: list[ArmConfig] = Field(default_factory=lambda: [ArmConfig(name="left"),
                                                          ArmConfig(name="right", mirror=True)])

    @model_validator(mode="after")
    def _transport_fields(self) -> HostConfig:
        if self.transport == "ssh":
            missing = [f for f in ("user", "key_file", "known_hosts") if getattr(self, f) is None]
            if missing:
                raise ValueError(f"ssh transport needs {', '.join(missing)}")
            if not self.python.startswith("/"):
                raise ValueError("python must be an absolute interpreter path over ssh")
        names = [a.name for a in self.arms]
        if len(set(names)) != len(names):
            raise ValueError("arm names must be unique within a host")
        if not self.arms:
            raise ValueError("a host needs at least one arm")
        return self


class HumansConfig(_Strict):
    count: int = Field(2, ge=0, le=1000)
    kind: Literal["scripted", "gui"] = "scripted"


class AlgorithmConfig(_Strict):
    """Allocation hyperparameters (seed 8.3, Table 1; DESIGN.md section 4)."""

    name: str = "cur"
    t_T: int = Field(3, ge=1, description="minimum teleoperation time")
    t_R: int = Field(5, ge=1, description="hard reset time")
    t_I: int = Field(10, ge=0, description="C.U.R. initial period")
    u_hat: float = Field(0.05, ge=0.0, le=1.0, description="uncertainty threshold")
    r_hat: float = Field(0.5, ge=0.0, le=1.0, description="risk threshold")
    thrifty_alpha: float = Field(0.5, ge=0.0, le=1.0)
    thrifty_threshold: float = 0.0
    random_budget: float = Field(0.3, ge=0.0, le=1.0,
                                 description="Random: mean fraction of humans busy")


class LearningConfig(_Strict):
    ensemble_size: int = Field(5, ge=1, le=32)
    batch_size: int = Field(256, ge=1, le=65536)
    lr: float = Field(3e-4, gt=0, lt=1)
    augmentation_factor: int = Field(10, ge=1, le=100)
    gradient_steps: int = Field(1, ge=0, le=100, description="per timestep")
    demos: int = Field(375, ge=1, description="offline state-action pairs")
    critic_transitions: int = Field(1000, ge=0, description="BC rollouts for the critics")
    pretrain_steps: int = Field(300, ge=0)
    critic_pretrain_steps: int | None = Field(
        None, ge=0, description="critics' offline steps; None: pretrain_steps. The seed "
        "trains them 3000 steps; the goal critic needs ~600 at batch 64 (docs/notes/learning.md)")
    gamma_safe: float = Field(0.5, ge=0, le=1)
    gamma_goal: float = Field(0.999, ge=0, le=1)
    device: Literal["auto", "cpu", "cuda"] = "auto"

    @property
    def critic_steps(self) -> int:
        """The critics' offline gradient steps (``critic_pretrain_steps`` if set)."""
        return self.pretrain_steps if self.critic_pretrain_steps is None else (
            self.critic_pretrain_steps)


class TrialConfig(_Strict):
    steps: int = Field(250, ge=1, le=1_000_000)
    seed: int = 0
    out: str = "runs"


class FleetConfig(_Strict):
    name: Name = "twin"
    trial: TrialConfig = TrialConfig()
    humans: HumansConfig = HumansConfig()
    algorithm: AlgorithmConfig = AlgorithmConfig()
    learning: LearningConfig = LearningConfig()
    hosts: list[HostConfig] = Field(default_factory=lambda: [HostConfig(name="cell0"),
                                                             HostConfig(name="cell1")])

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


def _one_line(err: ValidationError, source: str) -> str:
    first = err.errors()[0]
    loc = ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in first["loc"])
    loc = loc.replace(".[", "[") or "(top level)"
    msg = first["msg"].removeprefix("Value error, ")
    if first["type"] == "extra_forbidden":
        fix = "remove it or check its spelling (unknown keys are errors)"
        msg = "unknown key"
    elif first["type"] == "missing":
        fix = "add it"
    else:
        got = first.get("input")
        fix = f"got {got!r}" if not isinstance(got, dict | list) else "see README, section Config"
    more = len(err.errors()) - 1
    tail = f" (+{more} more)" if more else ""
    return f"{source}: {loc}: {msg}; {fix}{tail}"


def parse_config(data: dict[str, Any], source: str = "config") -> FleetConfig:
    """Validate a dict into a FleetConfig, or raise ConfigError with one line."""
    try:
        return FleetConfig.model_validate(data)
    except ValidationError as err:
        raise ConfigError(_one_line(err, source)) from None


def load_config(path: str | Path | None) -> FleetConfig:
    """Read and validate a TOML config; ``None`` gives the built-in twin fleet."""
    if path is None:
        return default_twin_config()
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the config file ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: the config file is not UTF-8 text") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML ({exc})") from None
    return parse_config(data, str(p))


TWIN_U_HAT = 0.17
"""The twin's uncertainty threshold: the 75th percentile of its ensemble's uncertainty
in C.U.R. runs (the seed's 0.05 made 55% of the twin's arm-steps eligible)."""


def default_twin_config() -> FleetConfig:
    """2 twin hosts x 2 arms, 2 scripted humans, local transport, 250 steps, C.U.R.

    Pretraining is sized for a 2-core laptop (a few minutes); the paper-scale
    hyperparameters live in ``protocols/*.toml``. u_hat is the twin's calibrated 0.17,
    as in ``protocols/twin.toml`` (docs/notes/fleet.md).
    """
    return FleetConfig(algorithm=AlgorithmConfig(u_hat=TWIN_U_HAT),
                       learning=LearningConfig(pretrain_steps=120, critic_transitions=400))
