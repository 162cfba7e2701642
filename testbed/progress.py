"""The live progress bar of a trial (rich): steps, and the counters an operator watches.

Kept out of the loop (as Stable-Baselines3's ProgressBarCallback): the loop reports a
``StepOutcome``; this turns it into a bar with successes, hard resets, idle time,
human actions and ROHE. Pretraining phases get a bar of their own.
"""

from __future__ import annotations

from types import TracebackType
from typing import TYPE_CHECKING

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

if TYPE_CHECKING:
    from testbed.fleet import StepOutcome


class TrialProgress:
    def __init__(self, steps: int, num_humans: int, num_robots: int, label: str = "trial") -> None:
        self.steps = steps
        self.label = label
        self._progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(bar_width=24),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            TextColumn("{task.fields[counters]}"),
            console=Console(stderr=True),
            transient=False,
        )
        self._tasks: dict[str, TaskID] = {}

    def __enter__(self) -> TrialProgress:
        self._progress.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._progress.stop()

    def _task(self, name: str, total: int) -> TaskID:
        if name not in self._tasks:
            self._tasks[name] = self._progress.add_task(name, total=total, counters="")
        return self._tasks[name]

    def on_phase(self, name: str, done: int, total: int) -> None:
        self._progress.update(self._task(name, total), completed=done, total=total)

    def on_step(self, outcome: StepOutcome) -> None:
        s = outcome.status
        counters = (
            f"succ {s.successes}  resets {s.hard_resets}  idle {s.idle_time}  "
            f"human {s.human_actions}  ROHE {s.rohe:.3f}"
        )
        self._progress.update(
            self._task(self.label, self.steps), completed=s.t, counters=counters
        )
