"""Protocols: trials x algorithms x steps, run end to end, then reported.

A protocol file (``protocols/*.toml``) names the fleet (an inline ``[fleet]`` table,
validated like any config), the algorithms, the number of trials, their seeds and
steps. Runs go to ``<out>/<algorithm>-t<k>``; a run that already has its summary is
skipped and one without it is resumed, so a protocol interrupted on day one goes on
on day two with ``testbed protocol FILE`` again.
"""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from testbed.config import ConfigError, FleetConfig, _one_line
from testbed.priorities import ALGORITHM_NAMES
from testbed.report import Report, write_report
from testbed.runs import RunDir


class Protocol(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    trials: int = Field(3, ge=1, le=100)
    algorithms: list[str] = Field(default_factory=lambda: ["bc", "random", "fleet-ed", "cur"])
    steps: int = Field(250, ge=1)
    seeds: list[int] | None = None
    out: str = "runs/protocol"
    humans: Literal["scripted", "gui"] = "scripted"
    prompt_between_trials: bool = False
    prompt: str = "Put every cube back near the centre of its workspace, then press Enter."
    fleet: FleetConfig = FleetConfig()

    @model_validator(mode="after")
    def _check(self) -> Protocol:
        bad = [a for a in self.algorithms if a not in ALGORITHM_NAMES]
        if bad:
            raise ValueError(f"unknown algorithm {bad[0]!r}; use {', '.join(ALGORITHM_NAMES)}")
        if self.seeds is not None and len(self.seeds) != self.trials:
            raise ValueError("seeds must have one seed per trial")
        return self

    def seed(self, k: int) -> int:
        return self.seeds[k] if self.seeds is not None else k


def load_protocol(path: Path) -> Protocol:
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the protocol file ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    try:
        return Protocol.model_validate(data)
    except ValidationError as err:
        raise ConfigError(_one_line(err, str(path))) from None


def run_protocol(proto: Protocol, out: str | None = None, ask: bool = True) -> Report:
    from testbed.progress import TrialProgress
    from testbed.trial import TrialOptions, run_trial

    folder = Path(out or proto.out)
    folder.mkdir(parents=True, exist_ok=True)
    cfg = proto.fleet
    for k in range(proto.trials):
        if k > 0 and proto.prompt_between_trials and ask:
            _prompt(f"trial {k + 1}/{proto.trials}: {proto.prompt}")
        for algorithm in proto.algorithms:
            name = f"{algorithm}-t{k}"
            run = RunDir(folder / name)
            if run.summary.exists():
                continue
            opts = TrialOptions(
                algorithm=algorithm,
                steps=proto.steps,
                seed=proto.seed(k),
                out=str(folder),
                humans=proto.humans,
                name=name,
            )
            resume = run.path if run.state.exists() else None
            if run.path.exists() and resume is None:
                _discard(run.path)
            with TrialProgress(proto.steps, cfg.humans.count, len(cfg.robot_names),
                               label=name) as bar:
                run_trial(cfg, opts, resume=resume, on_step=bar.on_step, progress=bar.on_phase)
    return write_report([folder], folder)


def _discard(path: Path) -> None:
    """A run folder that died before its first checkpoint holds nothing worth keeping."""
    import shutil

    shutil.rmtree(path)


def _prompt(text: str) -> None:
    if not sys.stdin.isatty():
        sys.stderr.write(f"{text} (no terminal: going on)\n")
        return
    input(f"{text} ")


__all__: list[Any] = ["Protocol", "load_protocol", "run_protocol"]
