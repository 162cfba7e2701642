"""The operator consoles: where the fleet's humans see their requests and answer them.

Two consoles implement ``testbed.core.humans.Humans`` for people, and behave the same:

* ``ConsoleHumans`` (``gui.console``, ``--humans gui``): OpenCV windows on the
  controller's desktop, one per human (a process each) and a fleet overview;
* ``WebHumans`` (``gui.web``, ``--humans web``): the same console as a page in each
  human's own browser, served by the controller.

What they share: ``gui.console_core.ConsoleCore`` (the Humans calls, pause and stop, one
``gui.desk.Desk`` per human deciding which request is shown and which input counts),
the drawing (``gui.draw`` renders ``gui.view.ConsoleView`` data on the geometry of
``gui.layout``, with the cube and workspace from ``gui.scene``) and the input mapping
(``gui.keys``: keys, clicks and buttons to commands). See ``docs/notes/gui.md`` and
``docs/notes/web.md``.

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
