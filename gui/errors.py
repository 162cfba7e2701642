"""The console's two exceptions, named for what the caller must do about them.

* ``ConsoleUnavailable``: the console cannot open a window here (no window system, the
  headless OpenCV build, no OpenCV). Raised by ``ConsoleHumans(...)`` with ONE line
  that says what to do, so the CLI can print it and exit instead of showing a
  traceback from deep inside Qt.
* ``StopRequested``: a human asked for a graceful stop (Esc, then ``y``), or a console
  window vanished. Raised by ``ConsoleHumans.act`` and ``.show``; it is a
  ``testbed.core.humans.HumansStopRequested`` so the fleet loop catches it without
  knowing the GUI exists.
"""

from __future__ import annotations

from testbed.core.humans import HumansStopRequested


class ConsoleUnavailable(RuntimeError):
    """No window can be opened here; the message (one line) says how to get one."""


class StopRequested(HumansStopRequested):
    """A human confirmed a graceful stop of the trial (or a console window was lost)."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason
