"""Metrics of a run, recomputed from its steps only: the summary, the curves, ROHE.

Why one module: every number the project reports (summary.json, the protocol table,
the cumulative plots, the live counters after a resume) comes from :func:`summarize`
or :func:`cumulative` over ``steps.jsonl`` rows, so the report and the trial can never
disagree, and ROHE is computed one way only: the paper's
``(M / N) * successes / (1 + human_actions)``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from testbed.core.types import Mode
from testbed.records.steps import HUMAN_MODES, IDLE_MODES, RecordError

__all__ = ["cumulative", "rohe", "summarize"]


def rohe(successes: float, human_actions: float, num_humans: int, num_robots: int) -> float:
    """Return on human effort, the paper's formula: (M / N) * successes / (1 + actions)."""
    if num_robots <= 0:
        return 0.0
    return (num_humans / num_robots) * successes / (1.0 + human_actions)


def _per_step_counts(steps: Sequence[Mapping[str, Any]]) -> dict[str, npt.NDArray[np.int64]]:
    n = len(steps)
    out = {k: np.zeros(n, dtype=np.int64) for k in
           ("t", "robots", "successes", "hard_resets", "idle_time", "human_actions",
            "teleop_steps", "reset_steps", "fault_steps", "refused_steps")}
    last_t: int | None = None
    for i, step in enumerate(steps):
        t = step["t"]
        if last_t is not None and t <= last_t:
            raise RecordError(f"step {i}: t={t} does not increase (previous t={last_t})")
        last_t = t
        out["t"][i] = t
        rows: Iterable[Mapping[str, Any]] = step["robots"]
        for row in rows:
            mode = row["mode"]
            out["robots"][i] += 1
            out["successes"][i] += bool(row["success"])
            out["hard_resets"][i] += bool(row["violation"])
            out["idle_time"][i] += mode in IDLE_MODES
            out["human_actions"][i] += mode in HUMAN_MODES
            out["teleop_steps"][i] += mode == Mode.TELEOP.value
            out["reset_steps"][i] += mode == Mode.RESET.value
            out["fault_steps"][i] += mode == Mode.FAULT.value
            out["refused_steps"][i] += mode == Mode.REFUSED.value
    return out


def summarize(steps: Sequence[Mapping[str, Any]], algorithm: str, num_humans: int,
              num_robots: int | None = None) -> dict[str, Any]:
    """Every metric of the run-record schema (docs/ARCHITECTURE.md) from the step rows
    (the one place they are made).

    ``num_robots`` defaults to the most robots any step lists. Extra keys beyond the
    contract: ``teleop_steps``, ``reset_steps``, ``fault_steps``, ``refused_steps``
    (arm-steps the host refused to push: counted in none of the contract's metrics),
    ``last_t``.
    """
    counts = _per_step_counts(steps)
    if num_robots is None:
        num_robots = int(counts["robots"].max()) if len(steps) else 0
    totals = {k: int(counts[k].sum()) for k in
              ("successes", "hard_resets", "idle_time", "human_actions",
               "teleop_steps", "reset_steps", "fault_steps", "refused_steps")}
    return {
        "algorithm": algorithm,
        "steps": len(steps),
        "num_robots": num_robots,
        "num_humans": num_humans,
        "successes": totals["successes"],
        "hard_resets": totals["hard_resets"],
        "idle_time": totals["idle_time"],
        "human_actions": totals["human_actions"],
        "rohe": rohe(totals["successes"], totals["human_actions"], num_humans, num_robots),
        "teleop_steps": totals["teleop_steps"],
        "reset_steps": totals["reset_steps"],
        "fault_steps": totals["fault_steps"],
        "refused_steps": totals["refused_steps"],
        "last_t": int(counts["t"][-1]) if len(steps) else None,
    }


def cumulative(steps: Sequence[Mapping[str, Any]], num_humans: int | None = None,
               num_robots: int | None = None) -> dict[str, npt.NDArray[Any]]:
    """Cumulative curves over timesteps for the plots: one array entry per step.

    Keys: ``t`` and cumulative ``successes``, ``hard_resets``, ``idle_time``,
    ``human_actions``; with ``num_humans`` also ``rohe`` (each entry = the ROHE of the
    run cut at that step). The last entries equal :func:`summarize`'s totals.
    """
    counts = _per_step_counts(steps)
    out: dict[str, npt.NDArray[Any]] = {"t": counts["t"]}
    for k in ("successes", "hard_resets", "idle_time", "human_actions"):
        out[k] = np.cumsum(counts[k])
    if num_humans is not None:
        if num_robots is None:
            num_robots = int(counts["robots"].max()) if len(steps) else 0
        if num_robots > 0:
            out["rohe"] = ((num_humans / num_robots) * out["successes"]
                           / (1.0 + out["human_actions"]))
        else:
            out["rohe"] = np.zeros(len(steps))
    return out
