"""The twin's declaration: what the registry (``testbed.core.backend_registry``) finds of it.

A simulation: no person at the robot, so scripted humans teleoperate it from its
expert, protocols fan it out on Ray workers and evaluate the expert's row; its arms are
cells of their own (separate PyBullet worlds), and it has nothing to calibrate, lock
or stop (a stroke is one simulation call of milliseconds).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, ClassVar

from drivers.backends.plugin import BackendPlugin
from drivers.backends.twin.twin_host import TwinHost
from testbed.core.backend_registry import Capabilities

if TYPE_CHECKING:
    from drivers.backends.base import HostBackend
    from testbed.core.host_config import HostBase

__all__ = ["BACKEND", "TwinPlugin"]


class TwinPlugin(BackendPlugin):
    name: ClassVar[str] = "twin"
    host_model: ClassVar[type[HostBase]] = TwinHost
    capabilities: ClassVar[Capabilities] = Capabilities(simulated=True)
    extra: ClassVar[str | None] = "twin"
    verify_imports: ClassVar[tuple[str, ...]] = ("drivers.backends.twin.twin_backend",
                                                 "sim_twin.cell", "cv2")
    nominal_push_s: ClassVar[float | None] = 0.01
    """A simulated stroke: 8 ms a fleet step measured (2 hosts x 2 arms over local
    pipes, 80 demonstrations in 21 steps, a 2-core machine under load, issue 44)."""

    def add_agent_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--no-physics", action="store_true",
                            help="twin: canned images, no simulation (benchmarks)")

    def agent_argv(self, host: HostBase) -> list[str]:
        return [] if getattr(host, "physics", True) else ["--no-physics"]

    def backend_kwargs(self, args: argparse.Namespace) -> dict[str, Any] | str:
        return {"physics": not args.no_physics}

    def make_backend(self, *, arms: Sequence[str], mirror: Sequence[bool], seed: int,
                     calibrating: Sequence[str] = (), physics: bool = True,
                     **_: Any) -> HostBackend:
        """A twin cell, or without physics canned images; the twin ignores the fields of
        other robots (crops, calibrations): its picture is its own."""
        from drivers.backends.twin.twin_backend import CannedTwinBackend, TwinBackend

        if not physics:
            return CannedTwinBackend(seed, arms, mirror)
        return TwinBackend(seed, arms, mirror)


BACKEND = TwinPlugin()
