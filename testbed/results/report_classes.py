"""The report's table of frame classes: per run, who produced its frames and how its
arms' episodes ended (issue 30).

Why: learning by class weighs a run's frames by class (robot, pre-intervention,
teleop, reset) and keeps the robot's pushes by their episode's outcome, so the report
says how much of each a run holds before anyone reads a learning curve: a run with
most of its robot pushes pre-intervention, or few episodes ending in a success, feeds
the learner something else than its successes count suggests. The counts come from
``testbed.records.run_classes`` (the data store and the run's own k; a run without a
store from steps.jsonl, said under the table).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from testbed.records.run_classes import run_classes
from testbed.records.steps import RecordError
from testbed.records.store import RunDataError
from testbed.results.report_tables import Table

__all__ = ["ClassCounts", "class_counts", "classes_table"]

CLASSES = ("robot", "pre_intervention", "teleop", "reset", "none")
"""The classes a run's frames can have (``demo`` never: the demonstrations are theta_0's)."""
OUTCOMES = ("success", "violation", "goal_change", "unknown", "open")


@dataclass
class ClassCounts:
    """One run's frames per class and episodes per outcome, the k they used."""

    pre_steps: int
    classes: dict[str, int]
    outcomes: dict[str, int]
    source: str
    notes: list[str] = field(default_factory=list)


def class_counts(path: Path) -> ClassCounts | None:
    """``path``'s counts, or None when its records cannot be read for them."""
    try:
        rc = run_classes(path)
    except (RunDataError, RecordError, OSError, ValueError, KeyError):
        return None
    return ClassCounts(rc.pre_steps, rc.class_counts(), rc.outcome_counts(), rc.source,
                       list(rc.notes))


def classes_table(runs: Sequence[tuple[str, str, ClassCounts | None]]) -> Table:
    """One row per run (its group and folder name): frames per class, episodes per
    outcome; a run whose counts came from steps.jsonl gets its notes under the table."""
    header = ["run", "algorithm", "k", *(c.replace("_", " ") for c in CLASSES),
              *(f"ep. {o.replace('_', ' ')}" for o in OUTCOMES)]
    rows: list[list[str]] = []
    csv_rows: list[list[object]] = [["run", "algorithm", "k", "source", *CLASSES,
                                     *(f"episodes_{o}" for o in OUTCOMES)]]
    notes: list[str] = []
    for name, group, c in runs:
        if c is None:
            rows.append([name, group, "-", *["-"] * (len(CLASSES) + len(OUTCOMES))])
            notes.append(f"{name}: its records could not be read for classes")
            continue
        cells = [c.classes[k] for k in CLASSES] + [c.outcomes[o] for o in OUTCOMES]
        rows.append([name, group, str(c.pre_steps), *map(str, cells)])
        csv_rows.append([name, group, c.pre_steps, c.source, *cells])
        if c.notes:
            notes.append(f"{name}: " + "; ".join(c.notes))
    return Table("classes", "Frame classes per run (frames per class; episodes per outcome, "
                 "each arm's episode once; k: the pre-intervention window in steps)",
                 header, rows, notes, csv_rows)
