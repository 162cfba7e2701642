"""What the humans taught (issue 30): each way's learning gain per human action.

A protocol with ``evaluate_start = true`` evaluates, in every trial, the policy its runs
started from (theta_0, ``eval:theta0``) beside each run's final policy (``eval:<way>``),
under the same conditions (the policy alone, humans for hard resets only). The gain of a
run is what its humans' time bought: ``(eval successes - theta_0's) / human actions``,
the trial's own theta_0 subtracted, so the pairs by trial compare like with like. This
table puts it beside the run's ROHE, hard resets and idle time, each with its interval
and paired against the reference (C.U.R. as today) with the exact sign-flip p.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from typing import TYPE_CHECKING, Any, Final

from testbed.records.run_dir import EVAL_PREFIX
from testbed.results.report_tables import Table, interval_table, paired_table

if TYPE_CHECKING:
    from testbed.results.run_record import RunRecord

START_GROUP: Final = f"{EVAL_PREFIX}theta0"
"""The evaluation row of the policy a trial's runs start from (``protocol.START``)."""
GAIN_METRICS: Final = ("eval_successes", "learning_gain", "rohe", "hard_resets", "idle_time")


def gain_rows(learning: Sequence[RunRecord], evaluations: Sequence[RunRecord]
              ) -> dict[str, dict[Hashable, dict[str, float]]]:
    """Per way and trial: its final policy's eval successes, the learning gain per human
    action, and the run's ROHE, hard resets and idle time (runs without both evaluations
    left out)."""
    start = {r.trial: float(r.summary["successes"]) for r in evaluations
             if r.group == START_GROUP}
    final = {(r.group.removeprefix(EVAL_PREFIX), r.trial): float(r.summary["successes"])
             for r in evaluations}
    out: dict[str, dict[Hashable, dict[str, float]]] = {}
    for r in learning:
        alone, before = final.get((r.group, r.trial)), start.get(r.trial)
        if alone is None or before is None:
            continue
        actions = float(r.summary["human_actions"])
        out.setdefault(r.group, {})[r.trial] = {
            "eval_successes": alone,
            "learning_gain": (alone - before) / actions if actions else math.nan,
            "rohe": float(r.summary["rohe"]),
            "hard_resets": float(r.summary["hard_resets"]),
            "idle_time": float(r.summary["idle_time"]),
        }
    return out


def gain_tables(learning: Sequence[RunRecord], evaluations: Sequence[RunRecord],
                reference: str, key_label: Any) -> list[Table]:
    """The gain's intervals and its pairs against ``reference`` (none without theta_0's
    evaluation)."""
    rows = gain_rows(learning, evaluations)
    if not rows:
        return []
    tables = [interval_table(
        "gain-intervals", "What the humans taught: each final policy alone against the "
        "trial's theta_0, per human action (learning gain = (eval successes - theta_0's) / "
        "human actions)", "algorithm", {g: list(by.values()) for g, by in rows.items()},
        GAIN_METRICS)]
    if reference in rows and len(rows) > 1:
        tables.append(paired_table("gain-paired", f"What the humans taught, paired against "
                                   f"{reference}", "algorithm", rows, reference, GAIN_METRICS,
                                   key_label))
    return tables
