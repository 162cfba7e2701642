"""What one console window shows, as plain data: the seam between logic and drawing.

The per-human state machine (``gui.desk``) decides *what* to show and the drawing
module (``gui.draw``) decides *how*; this dataclass is all they share, so both are
testable alone (the drawing from hand-made views, the logic without OpenCV).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from gui.layout import CubeMarker, Point
from testbed.core.types import HumanRequest


class Phase(StrEnum):
    IDLE = "idle"
    """No arm assigned to this human."""
    CHOOSE = "choose"
    """Teleop: waiting for this human's push."""
    SENT = "sent"
    """Teleop: the push was handed to the fleet; waiting for the next image."""
    RESET = "reset"
    """Hard reset: waiting for Enter."""
    RESET_CONFIRMED = "reset_confirmed"
    """Hard reset: Enter pressed (or already delivered); the arm may still be held."""


@dataclass(frozen=True, slots=True)
class ConsoleView:
    human: int
    phase: Phase
    request: HumanRequest | None = None
    t: int | None = None
    cube: CubeMarker | None = None
    markers: tuple[Point, ...] = ()
    """Face marker k's window coordinates (empty unless teleop)."""
    sent_action: int | None = None
    queued: int = 0
    """Further requests waiting for this human after the one shown."""
    paused: bool = False
    confirming_stop: bool = False
    stop_requested: bool = False
    name: str | None = None
    """The human's name (the config's ``humans.people``), None when unnamed."""


def human_label(human: int, name: str | None = None) -> str:
    """How every console names human ``human``: ``"ana (human 0)"``, or ``"human 0"``
    when unnamed.

    The name is who the person is (the records and the report use it); the index stays
    beside it because the step rows, the tokens and a lab's scripts count humans by
    index, and one label everywhere (titles, header, links, pages) lets an operator match
    a window to a line of the records.
    """
    return f"{name} (human {human})" if name else f"human {human}"
