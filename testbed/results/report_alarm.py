"""The report's table of the monitor algorithm at work (issue 36, item 4): per run of
``monitor``, when its alarm became ready, who its people went to and why, and the
threshold it ended with.

Why from the rows: each arm's row keeps the alarm's score and, once ready, its threshold
(``monitor.alarm_score``, ``monitor.alarm_threshold``), and the key (c, a, s, u, r) says
why an arm was eligible; so the table needs nothing but steps.jsonl, like the rest of the
report.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from testbed.records.steps import RecordError, read_steps
from testbed.results.report_tables import Table

__all__ = ["alarm_table"]

_NAMES = ("c", "a", "s", "u", "r")


def _why(key: Sequence[float]) -> str | None:
    """The key's first positive entry (the reason an arm was eligible), or None."""
    for name, v in zip(_NAMES, key, strict=False):
        if v != 0:
            return name if v > 0 else None
    return None


def _run_row(path: Path) -> list[Any] | None:
    try:
        rows = read_steps(path / "steps.jsonl", validate=False)
    except (OSError, RecordError):
        return None
    ready_at: int | None = None
    threshold = float("nan")
    started = {"c": 0, "a": 0, "u": 0, "r": 0}
    alarmed = 0
    for row in rows:
        for r in row["robots"]:
            mon = r.get("monitor") or {}
            if "alarm_threshold" in mon:
                ready_at = int(row["t"]) if ready_at is None else ready_at
                threshold = float(mon["alarm_threshold"])
            why = _why(r.get("key", []))
            alarmed += why == "a"
            if r.get("served") == 0 and why in started:  # an intervention's first step
                started[why] += 1
    return [path.name, "-" if ready_at is None else str(ready_at), alarmed,
            started["c"], started["a"], started["u"] + started["r"],
            "-" if threshold != threshold else f"{threshold:.3f}"]


def alarm_table(paths: Sequence[Path]) -> Table | None:
    """One row per run of the monitor algorithm (None when there is none)."""
    rows = [r for p in paths if (r := _run_row(p)) is not None]
    if not rows:
        return None
    header = ["run", "alarm ready at step", "arm-steps alarmed", "resets started",
              "teleops on an alarm", "teleops by C.U.R.'s rule (before ready)",
              "last threshold"]
    return Table("monitor-alarm", "The monitor algorithm at work: when its alarm was ready, "
                 "whom its people went to and why", header,
                 [[str(c) for c in r] for r in rows],
                 ["Before the alarm has its successful episodes (1/alpha - 1) the monitor "
                  "runs as C.U.R. (u, r); from then on a person goes only where the alarm "
                  "fires (a) or to a reset (c). An intervention counts once, at its first "
                  "step, under the key entry that made its arm eligible "
                  "(testbed/fleet/monitor_priority.py)."],
                 [["run", "ready_at", "alarmed", "resets", "alarm_teleops", "cur_teleops",
                   "threshold"], *rows])
