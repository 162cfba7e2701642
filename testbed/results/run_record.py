"""One finished run as the report reads it: its records summed up, its humans, its
classes, where it sits in a protocol or a sweep.

Why its own module: the report's parts (``report.py``, ``report_gain.py``,
``report_html.py``) all read runs, and a part that imports the report for the type of
its runs would make a circle of imports.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from testbed.core.types import HumanEstimate
from testbed.results.report_classes import ClassCounts
from testbed.results.report_humans import HumanCounts, Profile

__all__ = ["RunRecord"]


@dataclass
class RunRecord:
    path: Path
    algorithm: str
    num_humans: int
    summary: dict[str, Any]
    curves: dict[str, np.ndarray]
    parts: dict[str, int] = field(default_factory=dict)
    """Who made the successes and the violations (``rohe_parts``)."""
    group: str = ""
    """The table's row and the figure's line: the algorithm, or a sweep's point
    (run.json ``sweep.point``: ``humans.count-2``)."""
    meta: dict[str, Any] = field(default_factory=dict)
    """The run's run.json."""
    config: dict[str, Any] = field(default_factory=dict)
    """The run's config.toml (thresholds as resolved)."""
    humans: list[str] = field(default_factory=list)
    """The humans' names, by index."""
    human_counts: list[HumanCounts] = field(default_factory=list)
    human_estimates: list[HumanEstimate] = field(default_factory=list)
    """What the fleet's model said of each human at the run's end (``report_humans``)."""
    human_profiles: list[Profile | None] = field(default_factory=list)
    """Each scripted human's profile (None: a person at a console)."""
    digest: str = ""
    """``steps_digest``: equal for runs with identical records."""
    classes: ClassCounts | None = None
    """Frames per class, episodes per outcome (``report_classes``); None: unreadable."""

    def __post_init__(self) -> None:
        self.group = self.group or self.algorithm

    @property
    def trial(self) -> tuple[str, int]:
        """What pairs runs: a protocol's trial index, else the seed (a sweep's or a
        trial's), as (kind, number)."""
        proto = self.meta.get("protocol", {})
        if "trial" in proto:
            return ("trial", int(proto["trial"]))
        seed = self.meta.get("sweep", {}).get("seed", self.meta.get("options", {}).get("seed"))
        return ("seed", int(seed if seed is not None else 0))

    @property
    def grid_index(self) -> tuple[int, tuple[Any, ...]]:
        """Where a sweep's point sits in its grid (run.json ``sweep.index``; older sweeps:
        their values, numbers as numbers)."""
        sweep = self.meta.get("sweep", {})
        values = tuple((0, v, "") if isinstance(v, int | float) else (1, 0, str(v))
                       for v in sweep.get("values", {}).values())
        return int(sweep.get("index", 1 << 30)), values
