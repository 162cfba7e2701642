"""The failure monitor's config: ``[monitor]``, how prediction is scored and the alarm
calibrated.

Why here: the monitor's room owns its schema (as ``[algorithm]`` lives with the fleet);
``testbed/core/config.py`` loads it and says every error in one line (exit 2).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, get_args

from pydantic import Field, ValidationInfo, field_validator

from testbed.core.config import StrictModel
from testbed.monitor.conformal import (
    DEFAULT_GAMMA,
    DEFAULT_WINDOW,
    AlarmKind,
    check_gamma,
    episodes_needed,
)
from testbed.monitor.failure_head import FailureHead, HeadError

__all__ = ["SCORES", "MonitorConfig", "Score"]

Score = Literal["risk", "ood_u", "ood", "uncertainty", "novelty", "fail_head"]
SCORES: tuple[str, ...] = get_args(Score)
"""What the alarm of the ``monitor`` algorithm may watch: a learned signal it computes
(the policy's, or the safety critic's risk), ``ood_u`` (``ood`` and the uncertainty
together; testbed/fleet/monitor_priority.py), or ``fail_head``, the failure head in the
file ``head`` names (testbed/monitor/failure_head.py). Not the goal critic's risk: the
monitor algorithm does not train that critic."""


class MonitorConfig(StrictModel):
    """How failure prediction is scored and the conformal alarm set (docs/notes/monitor.md)."""

    alpha: float = Field(0.05, description="the bound on the false-alarm rate per "
                         "successful episode, in (0, 1)")
    horizon: int = Field(5, ge=1, description="the largest k of 'a violation within the next "
                         "k steps' scored (k = 1..horizon)")
    recall: float = Field(0.8, gt=0.0, le=1.0, description="the share of failed episodes the "
                          "lead time and false alarms are read at")
    window: int = Field(DEFAULT_WINDOW, ge=1, description="the latest untouched successful "
                        "episodes (no teleop, no reset) the alarm calibrates on")
    alarm: AlarmKind = Field("aci", description="the alarm: \"aci\" (adaptive conformal "
                             "inference: its realised false-alarm rate is within a stated "
                             "bound of alpha for any drift of the scores) or \"split\" (split "
                             "conformal on the window: a bound only while the episodes stay "
                             "exchangeable); docs/notes/monitor.md")
    gamma: float = Field(DEFAULT_GAMMA, description="ACI's step in (0, 1]: the level moves "
                         "by gamma (alpha - fired) after each judged episode")
    score: Score = Field("risk", description="what the monitor algorithm's alarm watches ("
                         + ", ".join(SCORES) + "); the safety critic's risk by default: the "
                         "best single signal the twin measured (docs/notes/monitor.md)")
    head: Path | None = Field(None, validate_default=True, description="the failure head "
                              "(a failure-head.json that testbed report wrote) the alarm "
                              "watches with score = \"fail_head\"; relative to where testbed "
                              "runs")

    @classmethod
    def for_scoring(cls, raw: Mapping[str, Any]) -> MonitorConfig:
        """A run's ``[monitor]`` as its report reads it: how prediction is scored and the
        alarm calibrated, without the alarm's ``score`` and ``head`` (which the report
        does not use), so a head file moved since the run does not stop its report."""
        return cls.model_validate({k: v for k, v in raw.items() if k not in ("score", "head")})

    @field_validator("alpha")
    @classmethod
    def _alpha(cls, v: float) -> float:
        if not 0.0 < v < 1.0:
            raise ValueError("must be in (0, 1)")
        return float(v)

    @field_validator("gamma")
    @classmethod
    def _gamma(cls, v: float) -> float:
        try:
            return check_gamma(v)
        except ValueError:
            raise ValueError("must be in (0, 1]") from None

    @field_validator("head")
    @classmethod
    def _head(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        if v is None:
            if info.data.get("score") == "fail_head":
                raise ValueError('required with score = "fail_head": the failure-head.json '
                                 "testbed report wrote for earlier runs")
            return None
        try:
            FailureHead.load(v)
        except HeadError as exc:
            raise ValueError(str(exc)) from None
        return v

    @field_validator("window")
    @classmethod
    def _window(cls, v: int, info: object) -> int:
        alpha = getattr(info, "data", {}).get("alpha")
        if alpha is not None and v < episodes_needed(alpha):
            raise ValueError(f"must hold at least {episodes_needed(alpha)} episodes for "
                             f"alpha {alpha} (1/alpha - 1)")
        return int(v)
