"""Where each person is, said to the operator before a trial starts (issue 44).

Why: a hard reset is hands on the cube, so the allocator gives one only to a person on
site (``HumanProfile.where``; docs/notes/core.md, "Allocation rules"); a remote person is
given teleops only. Who is where is the config's, and an operator who starts a trial
should read it back, person by person, with what each will be given, before anyone is
asked for anything: a person listed on site who is at home would leave resets waiting.
The config itself refuses a fleet with nobody on site (``HumansConfig``).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import TextIO

from testbed.core.humans import REMOTE, place_words

__all__ = ["announce_places", "place_lines"]

_ANNOUNCED: set[tuple[str, ...]] = set()
"""The lines printed so far by this process (a protocol's trials print them once)."""


def place_lines(names: Sequence[str], places: Sequence[str]) -> list[str]:
    """One line per person: ``"people: ana: on site (teleop and hard resets)"``,
    ``"people: bo: remote (teleop only)"``, by index."""
    return [f"people: {name}: {place_words(where)}"
            for name, where in zip(names, places, strict=True)]


def announce_places(kind: str, names: Sequence[str], places: Sequence[str],
                    file: TextIO | None = None) -> list[str]:
    """Print :func:`place_lines` once per process (to ``file``, stderr by default) for
    people at a console (``kind`` gui or web), or for scripted humans when one is remote
    (a twin rehearsing a lab's split; all on site, the twin's trials print nothing new).
    Returns the lines printed (empty when none)."""
    if not places or (kind == "scripted" and REMOTE not in places):
        return []
    lines = place_lines(names, places)
    if tuple(lines) in _ANNOUNCED:
        return []
    _ANNOUNCED.add(tuple(lines))
    print("\n".join(lines), file=file if file is not None else sys.stderr, flush=True)
    return lines
