"""The trial's display: plain lines outside a terminal, the rich bar in one."""

from __future__ import annotations

import io
import re

import pytest
from rich.console import Console

from testbed.core.config import ConfigError
from testbed.core.types import FleetStatus
from testbed.experiments.progress import ENV, TrialProgress, progress_mode
from testbed.fleet.loop import StepOutcome

STAMP = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d ")
CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f]")  # ANSI escapes, \r, ...


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def outcome(t: int, steps: int, **counters: float) -> StepOutcome:
    status = FleetStatus(t=t, steps=steps, **counters)  # type: ignore[arg-type]
    return StepOutcome(t=t - 1, row={}, status=status)


def plain(buf: io.StringIO, steps: int = 25, label: str = "trial", **kw: object
          ) -> tuple[TrialProgress, Clock]:
    clock = Clock()
    console = Console(file=buf, width=40)  # a StringIO: not a terminal
    bar = TrialProgress(steps, 2, 4, label=label, console=console, clock=clock, **kw)
    return bar, clock


def lines(buf: io.StringIO) -> list[str]:
    text = buf.getvalue()
    assert text.endswith("\n")
    out = text.splitlines()
    for line in out:
        assert STAMP.match(line), line
        assert not CONTROL.search(line), repr(line)
        assert "…" not in line and "━" not in line, line
    return [STAMP.sub("", line) for line in out]


def run_trial(bar: TrialProgress, clock: Clock, steps: int, dt: float = 2.0) -> None:
    with bar:
        clock.t += 5.0
        bar.on_phase("collect", 8, 16)
        clock.t += 5.0
        bar.on_phase("collect", 16, 16)
        for k in range(1, 4):
            clock.t += 1.0
            bar.on_phase("pretrain policy", k, 3)
        for t in range(1, steps + 1):
            clock.t += dt
            bar.on_step(outcome(t, steps, successes=t // 5, hard_resets=t // 7,
                                idle_time=3 * t, human_actions=2 * t, rohe=0.25))


def test_plain_lines_outside_a_terminal() -> None:
    buf = io.StringIO()
    bar, clock = plain(buf)
    assert bar.mode == "plain"
    run_trial(bar, clock, 25)
    got = lines(buf)
    assert got[:5] == [
        "collect: started, 16 pairs",
        "collect: done, 16/16 in 0:00:10",
        "pretrain policy: started, 3 steps",
        "pretrain policy: done, 3/3 in 0:00:03",
        "trial: started, 25 steps",
    ]
    steps = [g for g in got if re.match(r"trial: \d+/25", g)]
    assert [int(g.split()[1].split("/")[0]) for g in steps] == [1, 10, 20, 25]
    assert steps[1] == ("trial: 10/25 (40%), elapsed 0:00:20, 2.00 s/step, ETA 0:00:30 | "
                        "successes 2, hard resets 1, idle 30, human actions 20, ROHE 0.250")
    assert steps[-1].startswith("trial: 25/25 (100%), elapsed 0:00:50, 2.00 s/step | ")
    assert got[-1] == "trial: done, 25/25 in 0:00:50"
    assert all(len(g) > 40 for g in steps)  # wider than the console: never cut to fit


def test_plain_step_line_every_30_s_when_steps_are_slow() -> None:
    buf = io.StringIO()
    bar, clock = plain(buf, steps=12)
    run_trial(bar, clock, 12, dt=11.0)
    steps = [g for g in lines(buf) if re.match(r"trial: \d+/12", g)]
    # 1 (first), 4 (33 s after 1), 7, 10 (every 10), 12 (last): 30 s or 10 steps
    assert [int(g.split()[1].split("/")[0]) for g in steps] == [1, 4, 7, 10, 12]
    assert "0.09 steps/s" not in steps[1] and "11.00 s/step" in steps[1]


def test_plain_last_step_shown_when_a_trial_stops_early() -> None:
    buf = io.StringIO()
    bar, clock = plain(buf, steps=100)
    run_trial(bar, clock, 13)  # the operator stopped it at step 13 of 100
    got = lines(buf)
    assert got[-2].startswith("trial: 13/100 (13%)")
    assert "successes 2, hard resets 1, idle 39, human actions 26" in got[-2]
    assert got[-1] == "trial: stopped, 13/100 in 0:00:26"


def test_plain_interrupted_phase_and_resumed_trial() -> None:
    buf = io.StringIO()
    bar, clock = plain(buf, steps=50)
    with pytest.raises(KeyboardInterrupt), bar:
        clock.t += 4
        bar.on_step(outcome(31, 50))  # resumed after step 30
        clock.t += 4
        bar.on_step(outcome(32, 50))
        raise KeyboardInterrupt
    got = lines(buf)
    assert got[0] == "trial: started, 50 steps, resuming after 30"
    assert got[1].startswith("trial: 31/50 (62%), elapsed 0:00:04, 4.00 s/step, ETA 0:01:16")
    assert got[2].startswith("trial: 32/50")
    assert got[3] == "trial: interrupted, 32/50 in 0:00:08"


def test_plain_is_flushed_at_once() -> None:
    class Stream(io.StringIO):
        flushes = 0

        def flush(self) -> None:
            Stream.flushes += 1
            super().flush()

    buf = Stream()
    bar, _ = plain(buf)
    with bar:
        bar.on_phase("collect", 1, 4)
        assert Stream.flushes >= 1 and buf.getvalue().endswith("collect: started, 4 pairs\n")


def test_bar_in_a_terminal() -> None:
    buf = io.StringIO()
    console = Console(file=buf, force_terminal=True, width=120)
    bar = TrialProgress(5, 2, 4, console=console)
    assert bar.mode == "bar"
    with bar:
        for t in range(1, 6):
            bar.on_step(outcome(t, 5, successes=1))
    text = buf.getvalue()
    assert "\x1b[" in text and "━" in text and "succ 1" in text
    assert not STAMP.search(text)


def test_env_switch(monkeypatch: pytest.MonkeyPatch) -> None:
    tty = Console(file=io.StringIO(), force_terminal=True)
    log = Console(file=io.StringIO())
    assert progress_mode(tty, "") == "bar" and progress_mode(log, "") == "plain"
    assert progress_mode(tty, "auto") == "bar" and progress_mode(log, "AUTO") == "plain"
    assert progress_mode(tty, "plain") == "plain" and progress_mode(log, "bar") == "bar"
    with pytest.raises(ConfigError, match=ENV):
        progress_mode(log, "fancy")

    monkeypatch.setenv(ENV, "plain")
    assert TrialProgress(5, 0, 0, console=tty).mode == "plain"
    monkeypatch.setenv(ENV, "bar")
    assert TrialProgress(5, 0, 0, console=log).mode == "bar"
    # the default stderr console: a terminal or not, "bar" draws the bar
    bar = TrialProgress(5, 0, 0)
    assert bar.mode == "bar" and bar._progress is not None
    assert bar._progress.console.is_terminal
    monkeypatch.delenv(ENV)
    auto = "bar" if Console(stderr=True).is_terminal else "plain"
    assert TrialProgress(5, 0, 0).mode == auto


def test_plain_phase_line_every_30_s_and_its_last_count_when_cut_short() -> None:
    buf = io.StringIO()
    bar, clock = plain(buf)
    with pytest.raises(RuntimeError), bar:
        for k in range(1, 9):  # 10 s a step: a line at 30 s, not one per step
            clock.t += 10
            bar.on_phase("pretrain policy", k, 300)
        raise RuntimeError("learner failed")
    got = lines(buf)
    assert got[0] == "pretrain policy: started, 300 steps"
    assert got[1].startswith("pretrain policy: 4/300 (1%), elapsed 0:00:40, 10.00 s/step")
    assert got[2].startswith("pretrain policy: 7/300")
    assert got[3].startswith("pretrain policy: 8/300")  # the last count, before it stopped
    assert got[4] == "pretrain policy: interrupted, 8/300 in 0:01:20"
    assert len(got) == 5


def test_the_step_line_shows_faulted_waiting_and_away_and_the_last_fault() -> None:
    """Issue 44: a healthy run at a glance. The step line says which arms are faulted,
    how many wait for a person (the longest wait), who is away and the newest fault;
    a run where all is well says nothing more."""
    from testbed.core.types import Mode, RobotStatus

    buf = io.StringIO()
    bar, clock = plain(buf, steps=2, every=1)
    robots = [RobotStatus("yumi-a/left", Mode.FAULT, None),
              RobotStatus("yumi-a/right", Mode.IDLE, None, None, 3),
              RobotStatus("cell1/left", Mode.AUTONOMOUS, None)]
    long = "agent on host yumi-a: backend error: " + "the motors are off " * 8
    with bar:
        clock.t += 1.0
        bar.on_step(outcome(1, 2))
        clock.t += 1.0
        status = FleetStatus(t=2, steps=2, robots=robots, away=[1],
                             last_fault=(1, "yumi-a/left", long))
        bar.on_step(StepOutcome(t=1, row={}, status=status))
    got = [g for g in lines(buf) if re.match(r"trial: \d/2", g)]
    assert " | " not in got[0].split(" | ", 1)[1]  # step 1: all well, nothing added
    tail = got[1].split(" | ")[2]
    assert tail.startswith("faulted 1 (yumi-a/left); waiting 1 (longest 3 steps); away: "
                           "human 1; last fault at step 1, yumi-a/left: agent on host "
                           "yumi-a: backend error: the motors")
    assert tail.endswith("...") and len(tail) < 220  # a long reason is cut, not the line


def test_a_collection_resumed_counts_its_eta_from_what_it_kept() -> None:
    """Issue 44: a collection that goes on from 300 kept pairs says so, and its speed and
    ETA count only the pairs of this run (300 kept pairs counted as done in 10 s would
    give an ETA of seconds for 75 pairs at 2 s a step)."""
    buf = io.StringIO()
    bar, clock = plain(buf, every_s=1.0)
    with bar:
        bar.on_phase_resumed("collect", 300, 375)
        for done in (304, 308):  # 4 arms: 4 pairs a step, 2 s a step
            clock.t += 2.0
            bar.on_phase("collect", done, 375)
    got = lines(buf)
    assert got[0] == "collect: started, 375 pairs, resuming after 300"
    assert got[1] == "collect: 304/375 (81%), elapsed 0:00:02, 2.00 pairs/s, ETA 0:00:36"
    assert got[2].startswith("collect: 308/375 (82%), elapsed 0:00:04, 2.00 pairs/s, ETA 0:00:34")


def test_the_bar_starts_a_resumed_phase_where_it_was() -> None:
    buf = io.StringIO()
    bar = TrialProgress(5, 2, 4, console=Console(file=buf, force_terminal=True, width=120))
    with bar:
        bar.on_phase_resumed("rollout", 600, 1000)
        assert bar._progress is not None
        (task,) = bar._progress.tasks
        assert (task.description, task.completed, task.total) == ("rollout", 600, 1000)
        bar.on_phase("rollout", 610, 1000)
        assert task.completed == 610 and len(bar._progress.tasks) == 1
