"""The algorithm's config: ``[algorithm]``, the allocation's hyperparameters.

Why here: the allocation and the priority functions read it (``testbed/fleet/``), so its
schema lives in their room; ``testbed/core/config.py`` loads it and says every error in
one line.
"""

from __future__ import annotations

import re
from typing import Literal

from pydantic import Field, field_validator

from testbed.core.config import StrictModel

__all__ = ["MATCH_BUDGET", "QUANTILE", "AlgorithmConfig", "quantile_of"]

QUANTILE = re.compile(r"q(0(\.\d+)?|1(\.0*)?|\.\d+)")


def quantile_of(value: object) -> float | None:
    """p of a threshold given as ``"q<p>"`` (``"q0.75"`` -> 0.75), else None."""
    if isinstance(value, str) and QUANTILE.fullmatch(value):
        return float(value[1:])
    return None


MATCH_BUDGET = re.compile(r"match:[a-z0-9][a-z0-9-]*")
"""``random_budget = "match:<algorithm>"``: Random gets the human effort of that algorithm."""


class AlgorithmConfig(StrictModel):
    """Allocation hyperparameters (the paper's 8.3, Table 1; docs/notes/core.md)."""

    name: str = "cur"
    t_T: int = Field(3, ge=1, description="minimum teleoperation time")
    t_R: int = Field(5, ge=1, description="hard reset time")
    t_I: int = Field(10, ge=0, description="C.U.R. initial period")
    u_hat: float | str = Field(
        0.05, description="uncertainty threshold in [0, 1], or 'q<p>' (e.g. 'q0.75'): that "
        "quantile of theta_0's uncertainty on its pretraining rollouts, resolved when the "
        "run starts and written into its config.toml")
    r_hat: float | str = Field(0.5, description="risk threshold, as u_hat")
    thrifty_alpha: float = Field(0.5, ge=0.0, le=1.0)
    thrifty_threshold: float = 0.0
    random_budget: float | str = Field(
        0.3, description="Random: the mean fraction of humans busy, or 'match:<algorithm>' "
        "(in a protocol: the fraction that algorithm's run of the same trial used)")
    operators: Literal["blind", "matched"] = Field(
        "blind", description="who gets an arm: 'blind', Algorithm 1 (the free humans in "
        "index order, as interchangeable); 'matched', the human expected to gain most on "
        "it, from the run's own records (testbed/fleet/operators.py), and a teleop left "
        "to the policy when every free human is expected to do worse than it")

    @field_validator("u_hat", "r_hat")
    @classmethod
    def _threshold(cls, v: float | str) -> float | str:
        if isinstance(v, str):
            if quantile_of(v) is None:
                raise ValueError("a number in [0, 1] or a quantile 'q<p>' with p in [0, 1], "
                                 "e.g. 'q0.75'")
            return v
        if not 0.0 <= v <= 1.0:
            raise ValueError(f"must be in [0, 1], got {v}")
        return float(v)

    @property
    def quantile_thresholds(self) -> dict[str, float]:
        """The thresholds given as quantiles: name -> p (empty when all are numbers)."""
        out: dict[str, float] = {}
        for name in ("u_hat", "r_hat"):
            q = quantile_of(getattr(self, name))
            if q is not None:
                out[name] = q
        return out

    @field_validator("random_budget")
    @classmethod
    def _budget(cls, v: float | str) -> float | str:
        if isinstance(v, str):
            if not MATCH_BUDGET.fullmatch(v):
                raise ValueError("a number in [0, 1] or 'match:<algorithm>', e.g. 'match:cur'")
            return v
        if not 0.0 <= v <= 1.0:
            raise ValueError(f"the fraction of humans busy must be in [0, 1], got {v}")
        return float(v)

    @property
    def budget_match(self) -> str | None:
        """The algorithm Random's budget matches (``match:<algorithm>``), else None."""
        if isinstance(self.random_budget, str):
            return self.random_budget.split(":", 1)[1]
        return None
