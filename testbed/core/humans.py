"""The humans contract: what the fleet loop asks of whoever answers interventions.

The fleet loop never knows who its humans are. Each timestep it hands the allocated
interventions to ``Humans.act`` and gets one answer per arm: a push for teleoperation,
or whether a hard reset is complete. The implementations live in their own rooms:
``testbed.experiments.scripted_humans.ScriptedHumans`` (the twin's "algorithmic human",
the paper's simulated experts), ``gui.console.ConsoleHumans`` (the operator console) and
``gui.web.WebHumans`` (the browser console: humans on their own devices, who may be
away, ``Presence``); ``testbed.experiments.build.make_humans`` picks one from a config.
Why here, in ``core``: ``gui`` implements this contract and may import only ``core``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final, Literal, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from testbed.core.types import FleetStatus, HumanRequest, HumanResponse


def unnamed_human(index: int) -> str:
    """What human ``index`` of a fleet is called when the config names no one
    (``[humans]`` without ``[[humans.people]]``: ``human0``, ``human1``...).

    Why one home, here: such a name says nothing beyond the index, so whatever takes a
    person's name out of a run (``testbed.records.run_dir.human_names``, the learner's
    labellers) must tell it from a name someone gave, and ``core`` is what the people's
    schema, the records and the learner all import."""
    return f"human{index}"


Place = Literal["on_site", "remote"]
"""Where a person is (``HumanProfile.where``): in the room with the arms, or elsewhere."""
ON_SITE: Final = "on_site"
REMOTE: Final = "remote"
PLACES: Final[tuple[Place, ...]] = ("on_site", "remote")


def place_words(where: str) -> str:
    """What a person at ``where`` is given, as the consoles and the start lines say it:
    ``"on site (teleop and hard resets)"`` or ``"remote (teleop only)"``.

    Why one home, here: a hard reset puts a cube back by hand, so only a person in the
    room can do it; the allocator gives a remote person teleops only, and every surface
    that names a person's place (both consoles, the lines printed before a trial) must
    say the same words. ``core``, because ``gui`` may import nothing else."""
    if where == ON_SITE:
        return "on site (teleop and hard resets)"
    if where == REMOTE:
        return "remote (teleop only)"
    raise ValueError(f"unknown place {where!r}; use one of {', '.join(PLACES)}")


def reset_taker(human: int, places: Sequence[str]) -> int:
    """Who answers a hard reset addressed to ``human``: that human when on site (or when
    the places are not known, or ``human`` is not among them), else one of the on-site
    people (the ``human``-th of them, round robin).

    Why: the allocator gives a remote person no reset, but the data collection before a
    trial (``testbed.experiments.pretraining``) addresses its resets by arm index, to
    whoever has that index; the consoles and the scripted humans route such a reset to
    a person in the room, so a remote person is never shown one."""
    if not 0 <= human < len(places) or places[human] != REMOTE:
        return human
    on_site = [j for j, p in enumerate(places) if p != REMOTE]
    return on_site[human % len(on_site)] if on_site else human


class HumansStopRequested(Exception):
    """A human asked for a graceful stop of the trial (Esc, confirmed, on the console)."""


@dataclass(frozen=True, slots=True)
class Presence:
    """Which humans can take an intervention this step (the web console's away humans).

    Humans on their own devices come and go: a human whose console page is closed is
    away. The fleet loop asks ``Humans.presence()`` (optional: humans without it are all
    present, always) before each allocation and hands ``available`` to the allocator,
    which never newly assigns an away human. A held intervention of an away human goes
    on for the console's grace period (the page may be back in a moment, a reload); a
    human away longer is in ``gone``, and the loop ends that human's intervention and
    records it (the step row's ``released``).
    """

    available: npt.NDArray[np.bool_]
    """(M,) True for a human who may be assigned this step."""
    gone: frozenset[int] = field(default_factory=frozenset)
    """Humans away past the grace period: any intervention they hold ends now."""


@runtime_checkable
class Humans(Protocol):
    """Every timestep: answer the interventions the allocator assigned."""

    def act(self, requests: Sequence[HumanRequest], t: int) -> dict[str, HumanResponse]: ...

    def show(self, t: int, status: FleetStatus) -> None: ...

    def close(self) -> None: ...


def presence_of(humans: Humans, t: int | None = None) -> Presence | None:
    """``humans.presence()`` if that kind of humans can be away, else None (all present).

    Humans whose presence depends on the step rather than on a clock (the scripted
    humans' ``availability``, drawn per step so a resumed trial draws as the
    uninterrupted one) have ``presence_at(t)`` instead; the loop passes ``t``."""
    at = getattr(humans, "presence_at", None)
    if t is not None and callable(at):
        return at(t)
    get = getattr(humans, "presence", None)
    return get() if callable(get) else None
