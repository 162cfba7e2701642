"""Thresholds from data, not from the report's seeds (issue 12, item 2).

``u_hat`` and ``r_hat`` may be given as quantiles (``"q0.75"``): the threshold is that
quantile of theta_0's own signal (uncertainty, or the safety critic's risk at pi(s)) on
its pretraining rollouts, the states the fleet visits first (``Learner.signals_on_data``).
A protocol's runs share theta_0, so they resolve to the same number; it is computed
when each run starts (a few hundred forward passes), before its first step, and
written into that run's config.toml (a resumed run reads it back, never recomputes)
and into run.json ``thresholds`` with the quantile and the number of states.

Why: a threshold tuned on the seeds a report then shows is fitted to the report. The
project's uncertainty is the ensemble's mutual information over log 4 (in [0, 1]), not
the paper's measure, so the paper's numbers (u_hat 0.05) do not carry over; a quantile
says what fraction of early states count as uncertain, which does.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol, TypeVar

import numpy as np

from testbed.core.config import ConfigError
from testbed.fleet.algorithm_config import AlgorithmConfig

SIGNAL = {"u_hat": "uncertainty", "r_hat": "risk"}


class _WithAlgorithm(Protocol):
    """A config with an ``[algorithm]`` section (the fleet's: ``FleetConfig``)."""

    @property
    def algorithm(self) -> AlgorithmConfig: ...

    def model_copy(self, *, update: Mapping[str, Any] | None = None, deep: bool = False
                   ) -> Any: ...


ConfigT = TypeVar("ConfigT", bound=_WithAlgorithm)


def resolve_thresholds(cfg: ConfigT, learner: Any, only: Mapping[str, float] | None = None,
                       ) -> tuple[ConfigT, dict[str, Any]]:
    """``cfg`` with the quantile thresholds (``only`` those, e.g. the ones the run's
    algorithm reads) replaced by their values on ``learner``'s data, and what was
    resolved (name -> quantile, value, signal, states). Unchanged when none is left."""
    wanted = cfg.algorithm.quantile_thresholds if only is None else dict(only)
    if not wanted:
        return cfg, {}
    signals = learner.signals_on_data()
    values: dict[str, float] = {}
    record: dict[str, Any] = {}
    for name, q in wanted.items():
        data = np.asarray(signals[SIGNAL[name]], dtype=np.float64)
        if data.size == 0:
            raise ConfigError(f"algorithm.{name} = 'q{q:g}': theta_0 has no data to take "
                              "the quantile of; give a number")
        values[name] = float(np.quantile(data, q))
        record[name] = {"quantile": q, "value": values[name], "signal": SIGNAL[name],
                        "states": int(data.size)}
    algorithm = cfg.algorithm.model_copy(update=values)
    resolved: ConfigT = cfg.model_copy(update={"algorithm": algorithm})
    return resolved, record
