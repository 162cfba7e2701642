"""What a trial is built from: its hosts and its humans, from a config.

Why one module: this is the one place in ``testbed/`` (with ``testbed.lab``) that
reaches the rooms that talk to the world, ``drivers`` (the host fleet) and ``gui``
(the consoles), and it imports them only inside the functions that build them, so
``import testbed`` never pulls in SSH, a window system or a web server
(docs/ARCHITECTURE.md, the import rules).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from testbed.core.config import FleetConfig, WebConsoleConfig
from testbed.core.humans import Humans
from testbed.experiments.scripted_humans import ScriptedHumans

if TYPE_CHECKING:
    from drivers.host_fleet import HostFleet

__all__ = ["build_hosts", "make_humans"]


def build_hosts(cfg: FleetConfig, seed: int, log_dir: Path | None = None) -> HostFleet:
    """The fleet's ``HostFleet``; with ``log_dir`` each host's agent log and the
    controller's events about it go to ``log_dir/<host>.log`` (docs/notes/drivers.md)."""
    from drivers.host_fleet import HostFleet

    if log_dir is None:
        return HostFleet(cfg.hosts, trial_seed=seed)
    return HostFleet(cfg.hosts, trial_seed=seed, log_dir=log_dir)


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

        humans: Humans = WebHumans.from_config(count, web if web is not None
                                               else WebConsoleConfig())
        return humans
    raise ValueError(f"unknown humans kind {kind!r}; use scripted, gui or web")


def shared_cells(cfg: FleetConfig) -> dict[str, str]:
    """Robot -> its cell, for the robots that share one with others: a YuMi host's arms
    work over one table, so a person resetting one has hands near the other (the loop
    holds the other's pushes, ``FleetLoop._hold_cells``). A twin host's arms are cells of
    their own (separate PyBullet worlds) and share nothing."""
    return {f"{h.name}/{a.name}": h.name for h in cfg.hosts for a in h.arms
            if h.backend == "yumi" and len(h.arms) > 1}
