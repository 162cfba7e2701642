"""``SlowArmBackend``: an arm whose push is a motion of seconds that ``stop()`` ends
midway, and, run as a script, the REAL agent serving it.

Why: protocol 3's control path (heartbeats answered during a motion, ``stop`` mid-push,
the watchdog, EOF mid-push) is only visible with a push that lasts; the twin's push is
over in milliseconds. The backend moves a fake arm one step every ``STEP_S`` until the
stroke is done or ``stop()`` is called, and appends every event (push start, stop, push
end, rest, close) with its ``time.monotonic()`` (one clock for every process on Linux)
and its pid to a JSON-lines file, so a test in another process measures latencies.

The seam (test-only): ``drivers.agent.main(argv, backend_factory=...)``; the agent's
command line cannot reach a test backend. ``python tests/drivers/slow_arm.py ARGV``
runs the agent with this backend; a leading ``-m drivers.agent`` is dropped, so the
script stands in for the agent in an argv built by ``drivers.transport.agent_argv``
(the fleet tests swap those two words for this file's path). Environment:
``SLOW_ARM_EVENTS`` (the events file; none: no file) and ``SLOW_ARM_PUSH_S`` (how long
a push moves when not stopped, default 3 s).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from drivers import agent
from drivers.backends.base import ArmOutcome, ArmView, HostBackend
from drivers.backends.twin import CannedTwinBackend
from drivers.errors import BackendError

STEP_S = 0.01
EVENTS_ENV = "SLOW_ARM_EVENTS"
PUSH_S_ENV = "SLOW_ARM_PUSH_S"


class SlowArmBackend(HostBackend):
    """Canned pictures; a push moves step by step for ``push_s`` or until stopped (then
    it raises ``BackendError``: the agent answers one line, no traceback)."""

    kind = "slow-arm"

    def __init__(self, arms: Sequence[str] = ("left", "right"),
                 mirror: Sequence[bool] = (False, True), *, push_s: float = 3.0,
                 events: str | None = None) -> None:
        self.inner = CannedTwinBackend(0, arms, mirror)
        self.push_s = push_s
        self.position = 0  # steps moved by the last push
        self._stop = threading.Event()
        self._events = Path(events) if events else None
        self._lock = threading.Lock()

    def event(self, what: str, **extra: Any) -> None:
        """One line of the events file (from the worker, or from the reader's stop)."""
        if self._events is None:
            return
        line = json.dumps({"event": what, "t": time.monotonic(), "pid": os.getpid(),
                           "thread": threading.current_thread().name, **extra})
        with self._lock, self._events.open("a") as f:
            f.write(line + "\n")

    @property
    def arm_names(self) -> tuple[str, ...]:
        return self.inner.arm_names

    @property
    def mirror(self) -> tuple[bool, ...]:
        return self.inner.mirror

    def observe(self) -> dict[str, ArmView]:
        return self.inner.observe()

    def push(self, faces: Mapping[str, int]) -> dict[str, ArmOutcome]:
        faces = self.check_faces(faces)
        self._stop.clear()
        steps = max(1, round(self.push_s / STEP_S))
        self.event("push_start", steps=steps)
        for step in range(steps):
            self.position = step
            if self._stop.wait(STEP_S):
                self.event("push_stopped", at=step)
                raise BackendError(f"push stopped after {step} of {steps} steps")
        self.event("push_done")
        return {arm: ArmOutcome(False, False) for arm in faces}

    def stop(self) -> None:
        self.event("stop")
        self._stop.set()

    def reset(self, arms: Sequence[str]) -> dict[str, bool]:
        return self.inner.reset(arms)

    def rest(self) -> None:
        self.event("rest")

    def close(self) -> None:
        self.event("close")


def read_events(path: Path, pid: int | None = None) -> list[dict[str, Any]]:
    """The events so far (of one agent process if ``pid``)."""
    if not path.exists():
        return []
    rows = [json.loads(ln) for ln in path.read_text().splitlines() if ln.strip()]
    return [r for r in rows if pid is None or r["pid"] == pid]


def _factory(args: argparse.Namespace, kwargs: dict[str, Any]) -> HostBackend:
    return SlowArmBackend(kwargs["arms"], kwargs["mirror"],
                          push_s=float(os.environ.get(PUSH_S_ENV, "3")),
                          events=os.environ.get(EVENTS_ENV))


def run_agent(argv: Sequence[str], factory: Callable[[argparse.Namespace, dict[str, Any]],
                                                   HostBackend]) -> int:
    """The REAL agent with a test backend: ``agent_argv``'s argv, a leading
    ``-m drivers.agent`` dropped (the seam every agent-as-a-script here stands on)."""
    args = list(argv)
    if args[:2] == ["-m", "drivers.agent"]:
        args = args[2:]
    return agent.main(args, backend_factory=factory)


def main(argv: Sequence[str]) -> int:
    return run_agent(argv, _factory)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
