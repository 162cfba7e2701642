"""What a trial is built from: its hosts and its humans, from a config; and which code
it runs (run.json ``code``).

Why one module: this is the one place in ``testbed/`` (with ``testbed.lab``) that
reaches the rooms that talk to the world, ``drivers`` (the host fleet, the build id)
and ``gui`` (the consoles), and it imports them only inside the functions that need
them, so
``import testbed`` never pulls in SSH, a window system or a web server
(docs/ARCHITECTURE.md, the import rules).
"""

from __future__ import annotations

import importlib.metadata
import platform
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from testbed.core.backend_registry import backend_of
from testbed.core.host_config import HostConfig
from testbed.core.humans import Humans, unnamed_human
from testbed.experiments.fleet_config import FleetConfig
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.people.people_config import HumanProfile, WebConsoleConfig
from testbed.people.places import announce_places

if TYPE_CHECKING:
    from drivers.host_fleet import HostFleet

__all__ = ["build_hosts", "code_identity", "make_humans"]


LIBRARIES = ("numpy", "pybullet", "kornia")
"""The libraries a run's numbers depend on besides torch (run.json ``numerics`` has it):
the arrays, the twin's physics, the augmentation; each recorded when installed."""


def code_identity() -> dict[str, Any]:
    """Which code this controller runs, for run.json ``code``: the checkout's commit,
    whether the product had uncommitted changes, the build id every host's agent must
    match (``drivers.build_id``, its one git reader: here, lazily, because this is the
    module of ``testbed.experiments`` that may reach ``drivers``), the Python and the
    versions of ``LIBRARIES`` (package metadata: cheap, nothing imported)."""
    from drivers.build_id import source_state

    state = source_state()
    libraries: dict[str, str] = {}
    for name in LIBRARIES:
        try:
            libraries[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return {"commit": state.commit, "dirty": state.dirty, "build": state.build,
            "python": platform.python_version(), "libraries": libraries}


def build_hosts(cfg: FleetConfig, seed: int, log_dir: Path | None = None, *,
                hosts: Sequence[HostConfig] | None = None) -> HostFleet:
    """The fleet's ``HostFleet``; with ``log_dir`` each host's agent log and the
    controller's events about it go to ``log_dir/<host>.log`` (docs/notes/drivers.md).
    ``hosts``: only these of the fleet's (``testbed check`` looks at controller hosts
    apart from the others, whose observation may move nothing real)."""
    from drivers.host_fleet import HostFleet

    chosen = list(cfg.hosts if hosts is None else hosts)
    if log_dir is None:
        return HostFleet(chosen, trial_seed=seed)
    return HostFleet(chosen, trial_seed=seed, log_dir=log_dir)


def make_humans(kind: str, count: int, web: WebConsoleConfig | None = None, *,
                people: Sequence[HumanProfile] = (), names: Sequence[str] = (),
                places: Sequence[str] | None = None, seed: int = 0,
                robots: Sequence[str] = (), resumed_at: int | None = None) -> Humans:
    """Build the humans of a trial; a console is imported only when asked for.

    ``web``: the browser console's settings (``humans.web`` of the config), read only
    for ``kind = "web"`` (default: ``WebConsoleConfig()``, loopback, random tokens).
    ``people``: the scripted humans' profiles (``humans.profiles``; none: perfect
    experts, as for collecting demonstrations), their draws seeded by ``seed`` and the
    arm's index in ``robots``. ``names``: what a console calls each person (the names
    of ``humans.people``, so the windows and pages say who is who, as the records do);
    empty: "human 0", "human 1", ... (a config that names nobody keeps its labels).
    ``resumed_at``: the step a resumed trial goes on from (the web console tells each
    person their link is the one given at the start). ``places``: each person's
    ``where`` (``"on_site"``, ``"remote"``), shown by the consoles; default: the
    ``people``'s. Before the humans are built, the operator is told each person's place
    and what they will be given (``testbed.people.places.announce_places``).
    """
    places = [p.where for p in people] if places is None else list(places)
    announce_places(kind, [p.name for p in people] if len(people) == len(places)
                    else [unnamed_human(i) for i in range(len(places))], places)
    if kind == "scripted":
        return ScriptedHumans(people, seed=seed, robots=robots)
    if kind == "gui":
        from gui.console import ConsoleHumans

        return ConsoleHumans(num_humans=count, names=names, places=places)
    if kind == "web":
        from gui.web import WebHumans

        humans: Humans = WebHumans.from_config(
            count, web if web is not None else WebConsoleConfig(), names=names,
            places=places, resumed_at=resumed_at)
        return humans
    raise ValueError(f"unknown humans kind {kind!r}; use scripted, gui or web")


def shared_cells(cfg: FleetConfig) -> dict[str, str]:
    """Robot -> its cell, for the robots that share one with others: a YuMi host's arms
    work over one table, so a person resetting one has hands near the other (the loop
    holds the other's pushes, ``FleetLoop._hold_cells``). A twin host's arms are cells of
    their own (separate PyBullet worlds) and share nothing."""
    return {f"{h.name}/{a.name}": h.name for h in cfg.hosts for a in h.arms
            if backend_of(h).capabilities.shared_cell and len(h.arms) > 1}
