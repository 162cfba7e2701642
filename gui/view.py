"""What one console window shows, as plain data: the seam between logic and drawing.

The per-human state machine (``gui.desk``) decides *what* to show and the drawing
module (``gui.draw``) decides *how*; this dataclass is all they share, so both are
testable alone (the drawing from hand-made views, the logic without OpenCV).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

from gui.layout import CubeMarker, Point
from testbed.core.humans import ON_SITE, REMOTE
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
    place: str | None = None
    """Where the human is (``"on_site"`` / ``"remote"``, the config's ``where``), None
    when the console was not told."""


def human_label(human: int, name: str | None = None) -> str:
    """How every console names human ``human``: ``"ana (human 0)"``, or ``"human 0"``
    when unnamed.

    The name is who the person is (the records and the report use it); the index stays
    beside it because the step rows, the tokens and a lab's scripts count humans by
    index, and one label everywhere (titles, header, links, pages) lets an operator match
    a window to a line of the records.
    """
    return f"{name} (human {human})" if name else f"human {human}"


def place_tag(place: str | None) -> str:
    """A person's place as a console shows it beside their label: ``"on site"``,
    ``"remote"``, or ``""`` when the console was not told (``testbed.core.humans.
    place_words`` says what each is given; a remote person's idle line says it too)."""
    if place is None:
        return ""
    if place == ON_SITE:
        return "on site"
    if place == REMOTE:
        return "remote"
    raise ValueError(f"unknown place {place!r}; use {ON_SITE!r} or {REMOTE!r}")


def check_places(places: Sequence[str], num_humans: int) -> tuple[str, ...]:
    """Each human's place (``"on_site"`` / ``"remote"``, the config's ``where``) as a
    console shows it, or a ValueError saying what is wrong; empty: not told."""
    given = tuple(places)
    if given and len(given) != num_humans:
        raise ValueError(f"places: need {num_humans} (one per human), got {len(given)}")
    for i, place in enumerate(given):
        try:
            place_tag(place)
        except ValueError as exc:
            raise ValueError(f"places[{i}]: {exc}") from None
    return given
