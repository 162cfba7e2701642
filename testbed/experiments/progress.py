"""The live progress of a trial: steps, and the counters an operator watches.

Kept out of the loop (as Stable-Baselines3's ProgressBarCallback): the loop reports a
``StepOutcome``; this turns it into a display with successes, hard resets, idle time,
human actions and ROHE. Pretraining phases (collect, pretrain policy, rollout, pretrain
critics) are reported through ``on_phase``; one that goes on from what an earlier try
kept through ``on_phase_resumed`` first, so its speed and ETA count this run's work only.

Two displays, chosen by ``TESTBED_PROGRESS`` (``auto``, the default; ``plain``; ``bar``):

- in a terminal, a rich bar per phase, redrawn in place;
- anywhere else (a log file, ``nohup``, tmux logging, a pipe into ``tee``), plain
  timestamped lines, each written whole and flushed at once: one when a phase starts
  and one when it ends, one every ``every`` steps or ``every_s`` seconds, whichever
  comes first, and always the last step. A rich bar there would come out once, at the
  end, in truncated 80-column cells ("collect ━━ 3… 0:… 0…").
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType
from typing import TYPE_CHECKING, Literal, TextIO

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

from testbed.core.config import ConfigError
from testbed.experiments.hooks import TrialHooks

if TYPE_CHECKING:
    from testbed.core.types import FleetStatus
    from testbed.fleet.loop import StepOutcome

ENV = "TESTBED_PROGRESS"
MODES = ("auto", "plain", "bar")
EVERY_STEPS = 10
"""Plain display: a step line every this many trial steps ..."""
EVERY_S = 30.0
"""... or after this many seconds without a line, whichever comes first."""

Mode = Literal["plain", "bar"]

_UNITS = {"collect": "pair", "rollout": "transition"}
"""What a phase counts (offline.py's names); ``pretrain ...`` counts steps, else items."""


def _unit(name: str) -> str:
    return "step" if name.startswith("pretrain") else _UNITS.get(name, "item")


def progress_mode(console: Console, env: str | None = None) -> Mode:
    """``bar`` or ``plain`` for this console, as ``TESTBED_PROGRESS`` asks (auto: a
    terminal gets the bar)."""
    raw = os.environ.get(ENV, "") if env is None else env
    want = raw.strip().lower() or "auto"
    if want not in MODES:
        raise ConfigError(f"{ENV}: {raw!r} is not one of {', '.join(MODES)}; "
                          "unset it for auto (the bar in a terminal, plain lines elsewhere)")
    if want == "auto":
        return "bar" if console.is_terminal else "plain"
    return "plain" if want == "plain" else "bar"


def _clock(seconds: float) -> str:
    """H:MM:SS, as rich's elapsed column."""
    s = max(0, int(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def _speed(done: int, seconds: float, unit: str) -> str:
    if done <= 0 or seconds <= 0:
        return ""
    rate = done / seconds
    return f"{rate:.2f} {unit}s/s" if rate >= 1 else f"{1 / rate:.2f} s/{unit}"


@dataclass
class _Phase:
    """One phase of the plain display: when it started, what was last seen and shown."""

    name: str
    total: int
    start: float
    first_done: int  # done before its first report (a resumed trial starts past 0)
    done: int = 0
    shown_done: int = -1
    shown_at: float = 0.0
    ended: bool = False


class _PlainLines:
    """Timestamped lines, written whole and flushed: what a log file should hold."""

    def __init__(self, stream: Callable[[], TextIO], every: int, every_s: float,
                 clock: Callable[[], float], now: Callable[[], float]) -> None:
        self._stream = stream
        self.every = every
        self.every_s = every_s
        self._clock = clock
        self._now = now
        self._phases: dict[str, _Phase] = {}
        self._last_event = clock()
        self._status: FleetStatus | None = None
        self._stepped: str | None = None  # the phase on_step reports

    def write(self, text: str) -> None:
        stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self._now()))
        out = self._stream()
        out.write(f"{stamp} {text}\n")
        out.flush()

    def _phase(self, name: str, done: int, total: int, what: str,
               resumable: bool = False, kept: bool = False) -> _Phase:
        """``resumable``: a first report past 0 comes after one unit of this run's work
        (a resumed trial's first step); ``kept``: the first report is what an earlier
        try kept, before any work of this run (a resumed collection)."""
        ph = self._phases.get(name)
        if ph is None:
            # it began when the previous report (or the display) ended: phases follow
            # one another, and the first report comes after its first unit of work
            first = (min(done, total) if kept
                     else max(0, min(done, total) - 1) if resumable else 0)
            ph = self._phases[name] = _Phase(name, total, self._last_event, first)
            self.write(f"{name}: started, {total} {what}s"
                       + (f", resuming after {first}" if first else ""))
        ph.total = total
        return ph

    def _line(self, ph: _Phase, now: float, unit: str) -> str:
        elapsed = now - ph.start
        done = ph.done - ph.first_done
        text = f"{ph.name}: {ph.done}/{ph.total}"
        if ph.total > 0:
            text += f" ({100 * ph.done / ph.total:.0f}%)"
        text += f", elapsed {_clock(elapsed)}"
        speed = _speed(done, elapsed, unit)
        if speed:
            text += f", {speed}"
            left = ph.total - ph.done
            if left > 0 and done > 0:
                text += f", ETA {_clock(math.ceil(left * elapsed / done))}"
        return text

    def _due(self, ph: _Phase, now: float, every: int | None) -> bool:
        if ph.done >= ph.total or ph.shown_done < 0:
            return True
        if every is not None and ph.done // every > ph.shown_done // every:
            return True
        return now - ph.shown_at >= self.every_s

    def _end(self, ph: _Phase, now: float, how: str = "done") -> None:
        ph.ended = True
        self.write(f"{ph.name}: {how}, {ph.done}/{ph.total} in {_clock(now - ph.start)}")

    def phase(self, name: str, done: int, total: int, kept: bool = False) -> None:
        """``kept``: the phase's first report, at what an earlier try kept."""
        now = self._clock()
        unit = _unit(name)
        fresh = name not in self._phases
        ph = self._phase(name, done, total, unit, kept=kept)
        ph.done = done
        if fresh:  # its start line stands for its first report
            ph.shown_done, ph.shown_at = done, now
        elif not ph.ended and ph.done < ph.total and self._due(ph, now, None):
            self._show(ph, now, self._line(ph, now, unit))
        if done >= total and not ph.ended:
            self._end(ph, now)
        self._last_event = now

    def step(self, name: str, total: int, status: FleetStatus) -> None:
        now = self._clock()
        ph = self._phase(name, status.t, total, "step", resumable=True)
        ph.done = status.t
        self._status, self._stepped = status, name
        if self._due(ph, now, self.every):
            self._show(ph, now, self._step_line(ph, now, status))
        if ph.done >= ph.total and not ph.ended:
            self._end(ph, now)
        self._last_event = now

    def _step_line(self, ph: _Phase, now: float, s: FleetStatus) -> str:
        health = s.health()
        return (f"{self._line(ph, now, 'step')} | successes {s.successes}, "
                f"hard resets {s.hard_resets}, idle {s.idle_time}, "
                f"human actions {s.human_actions}, ROHE {s.rohe:.3f}"
                + (", paused" if s.paused else "") + (f" | {health}" if health else ""))

    def _show(self, ph: _Phase, now: float, text: str) -> None:
        ph.shown_done = ph.done
        ph.shown_at = now
        self.write(text)

    def close(self, failed: bool) -> None:
        """Whatever did not finish: its last state (the last step is always shown)."""
        now = self._clock()
        for ph in self._phases.values():
            if ph.ended:
                continue
            if ph.shown_done != ph.done:
                if self._status is not None and ph.name == self._stepped:
                    self._show(ph, now, self._step_line(ph, now, self._status))
                else:
                    self._show(ph, now, self._line(ph, now, _unit(ph.name)))
            self._end(ph, now, "interrupted" if failed else "stopped")


class TrialProgress(TrialHooks):
    """The trial's display: a rich bar in a terminal, plain lines elsewhere (a
    ``TrialHooks``: ``on_phase`` and ``on_step``).

    ``console``: where to show it (default: stderr); ``mode``: ``plain`` or ``bar``
    (default: ``TESTBED_PROGRESS``, else by whether the console is a terminal);
    ``every``/``every_s``: the plain display's step line period.
    """

    def __init__(
        self,
        steps: int,
        num_humans: int,
        num_robots: int,
        label: str = "trial",
        *,
        console: Console | None = None,
        mode: Mode | None = None,
        every: int = EVERY_STEPS,
        every_s: float = EVERY_S,
        clock: Callable[[], float] = time.monotonic,
        now: Callable[[], float] = time.time,
    ) -> None:
        self.steps = steps
        self.label = label
        if console is None:
            console = Console(stderr=True)
            if mode is None and progress_mode(console) == "bar" and not console.is_terminal:
                console = Console(stderr=True, force_terminal=True)  # TESTBED_PROGRESS=bar
        self.mode: Mode = mode or progress_mode(console)
        self._plain: _PlainLines | None = None
        self._progress: Progress | None = None
        if self.mode == "plain":
            self._plain = _PlainLines(lambda: console.file, max(1, every), every_s, clock, now)
        else:
            self._progress = Progress(
                TextColumn("[bold]{task.description}"),
                BarColumn(bar_width=24),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                TimeRemainingColumn(),
                TextColumn("{task.fields[counters]}"),
                console=console,
                transient=False,
            )
        self._tasks: dict[str, TaskID] = {}

    def __enter__(self) -> TrialProgress:
        if self._progress is not None:
            self._progress.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._progress is not None:
            self._progress.stop()
        if self._plain is not None:
            self._plain.close(failed=exc_type is not None)

    def _task(self, name: str, total: int, done: int = 0) -> TaskID:
        assert self._progress is not None
        if name not in self._tasks:
            self._tasks[name] = self._progress.add_task(name, total=total, completed=done,
                                                        counters="")
        return self._tasks[name]

    def on_phase(self, name: str, done: int, total: int) -> None:
        if self._plain is not None:
            self._plain.phase(name, done, total)
            return
        assert self._progress is not None
        self._progress.update(self._task(name, total), completed=done, total=total)

    def on_phase_resumed(self, name: str, done: int, total: int) -> None:
        """A phase going on from ``done`` kept by an earlier try: its speed and ETA
        count only what this run does (the bar: rich's, from its own updates)."""
        if self._plain is not None:
            self._plain.phase(name, done, total, kept=True)
            return
        assert self._progress is not None
        self._task(name, total, done)

    def on_step(self, outcome: StepOutcome) -> None:
        s = outcome.status
        if self._plain is not None:
            self._plain.step(self.label, self.steps, s)
            return
        assert self._progress is not None
        health = s.health()
        counters = (
            f"succ {s.successes}  resets {s.hard_resets}  idle {s.idle_time}  "
            f"human {s.human_actions}  ROHE {s.rohe:.3f}" + (f"  | {health}" if health else "")
        )
        self._progress.update(
            self._task(self.label, self.steps), completed=s.t, counters=counters
        )
