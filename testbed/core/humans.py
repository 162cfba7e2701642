"""The humans behind one interface: scripted (twin) or people at the operator console.

The fleet loop never knows who its humans are. Each timestep it hands the allocated
interventions to ``Humans.act`` and gets one answer per arm: a push for teleoperation,
or whether a hard reset is complete. ``ScriptedHumans`` is the twin's "algorithmic
human" (the seed's simulated experts); ``gui.console.ConsoleHumans`` is the operator
console and ``gui.web.WebHumans`` the browser console (humans on their own devices, who
may be away: ``Presence``), both built lazily by ``make_humans`` so ``import testbed``
never pulls in a GUI or a web server.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from testbed.core.types import FleetStatus, HumanRequest, HumanResponse, InterventionKind

if TYPE_CHECKING:
    from testbed.core.config import WebConsoleConfig


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


class ScriptedHumans:
    """Ground-truth teleop and timed hard resets, for twin mode.

    Teleop pushes the host's expert action (``ArmObservation.expert_action``, which only
    a twin host reports). A hard reset is done at the end of the ``t_R``-th step it was
    served (DESIGN.md section 3), i.e. when ``served + 1 >= min_steps``.
    """

    def act(self, requests: Sequence[HumanRequest], t: int) -> dict[str, HumanResponse]:
        out: dict[str, HumanResponse] = {}
        for req in requests:
            if req.kind is InterventionKind.TELEOP:
                action = req.observation.expert_action
                if action is None:
                    raise RuntimeError(
                        f"{req.robot}: scripted humans need a twin host (no expert action); "
                        "use --humans gui with physical arms"
                    )
                out[req.robot] = HumanResponse(req.robot, action=int(action))
            else:
                done = req.served + 1 >= req.min_steps
                out[req.robot] = HumanResponse(req.robot, reset_done=done)
        return out

    def show(self, t: int, status: FleetStatus) -> None:
        return None

    def close(self) -> None:
        return None


def presence_of(humans: Humans) -> Presence | None:
    """``humans.presence()`` if that kind of humans can be away, else None (all present)."""
    get = getattr(humans, "presence", None)
    return get() if callable(get) else None


def make_humans(kind: str, count: int, web: WebConsoleConfig | None = None) -> Humans:
    """Build the humans of a trial; a console is imported only when asked for.

    ``web``: the browser console's settings (``humans.web`` of the config), read only
    for ``kind = "web"`` (default: ``WebConsoleConfig()``, loopback, random tokens).
    """
    if kind == "scripted":
        return ScriptedHumans()
    if kind == "gui":
        from gui.console import ConsoleHumans

        return ConsoleHumans(num_humans=count)
    if kind == "web":
        from gui.web import WebHumans
        from testbed.core.config import WebConsoleConfig

        humans: Humans = WebHumans.from_config(count, web if web is not None
                                               else WebConsoleConfig())
        return humans
    raise ValueError(f"unknown humans kind {kind!r}; use scripted, gui or web")
