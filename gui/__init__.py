"""The OpenCV operator console: one window per human and a fleet overview.

``ConsoleHumans`` implements ``testbed.core.humans.Humans`` for people: every timestep the
fleet loop hands it the interventions the allocator chose, each human answers in their
own window (a push for teleop, Enter for a finished hard reset), and the overview shows
the whole fleet. See ``docs/notes/gui.md`` for the threading model, keys and window
names.

``ConsoleHumans`` is exported lazily so ``import gui`` (and the exceptions) cost no
OpenCV import.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from gui.errors import ConsoleUnavailable, StopRequested

if TYPE_CHECKING:
    from gui.console import ConsoleHumans

__all__ = ["ConsoleHumans", "ConsoleUnavailable", "StopRequested"]


def __getattr__(name: str) -> Any:
    if name == "ConsoleHumans":
        from gui.console import ConsoleHumans  # lazy: keeps `import gui` light

        return ConsoleHumans
    raise AttributeError(f"module 'gui' has no attribute {name!r}")
