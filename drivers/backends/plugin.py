"""The agent's side of a backend plugin: its flags, how it builds its ``HostBackend``,
and which robot it locks.

Why: ``testbed.core.backend_registry.Backend`` declares what the controller's rooms need of a
backend (its host model, capabilities, extra). The agent on the robot host needs three
more things, and they belong in the same one object so that a robot stays one folder:
the command-line flags its host config turns into (``agent_argv`` on the controller,
``add_agent_arguments`` + ``backend_kwargs`` in the agent: one place writes and reads
them), the backend itself (``make_backend``, heavy imports inside), and, for a robot
with a controller, what the agent must own exclusively (``robot_identity``).

    controller:  host config --agent_argv--> argv --(SSH or a pipe)-->
    agent:       argv --add_agent_arguments/backend_kwargs--> kwargs --make_backend--> HostBackend
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

from testbed.core.backend_registry import Backend, BackendError, backend, backends

if TYPE_CHECKING:
    from drivers.backends.base import HostBackend
    from testbed.core.host_config import HostBase

__all__ = ["BackendPlugin", "agent_plugin", "agent_plugins", "arm_pairs"]


class BackendPlugin(Backend):
    """A backend's declaration with its agent-side calls (subclass it in ``plugin.py``).

    Every agent has the common flags (``--host``, ``--arms``, ``--mirror``, ``--seed``,
    ``--calibrate``, ``--lock-dir``, ``--lock-id``, ...: ``drivers/agent``); a backend
    adds its own. ``make_backend`` receives ``arms``, ``mirror``, ``seed`` and
    ``calibrating`` from the common flags and whatever ``backend_kwargs`` read."""

    def add_agent_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Add this backend's own agent flags (default: none)."""
        return None

    def agent_argv(self, host: HostBase) -> list[str]:
        """The flags of this backend's fields of ``host`` (controller side; no shell words)."""
        return []

    def backend_kwargs(self, args: argparse.Namespace) -> dict[str, Any] | str:
        """``make_backend``'s keyword arguments from this backend's flags, or one line
        saying what is wrong with them (the agent exits 2 with it)."""
        return {}

    def make_backend(self, *, arms: Sequence[str], mirror: Sequence[bool], seed: int,
                     calibrating: Sequence[str] = (), **kwargs: Any) -> HostBackend:
        """The host's backend (import the robot's clients here, not at module level)."""
        raise NotImplementedError(f"backend {self.name!r} builds no HostBackend")

    def controller_info(self, args: argparse.Namespace) -> dict[str, str] | None:
        """The controller as it names itself (``serial``, ``robotware``, ``system``), asked
        before the lock and sent in the hello; None: no controller, or it cannot be asked.
        Backends with the ``controller`` capability override it."""
        return None

    def controller_address(self, args: argparse.Namespace) -> str | None:
        """Where the robot's controller is (a URL), written into the robot's lock file so
        that a refused user is told which controller is held; None: not known."""
        return None

    def robot_identity(self, args: argparse.Namespace,
                       controller: Mapping[str, str] | None) -> str | None:
        """What this agent must own exclusively when no ``--lock-id`` is given; None: the
        agent owns what it drives (a twin's own cell). Backends with the ``robot_lock``
        capability override it."""
        return None


def arm_pairs(values: Sequence[str], flag: str) -> dict[str, str] | str:
    """Repeated ``--FLAG ARM=VALUE`` flags as a dict, or one line saying which is bad."""
    out: dict[str, str] = {}
    for v in values:
        arm, sep, rest = v.partition("=")
        if not sep or not arm or not rest:
            return f"{flag} expects ARM=VALUE, got {v!r}"
        out[arm] = rest
    return out


def agent_plugin(name: str) -> BackendPlugin:
    """The backend ``name`` with its agent-side calls; BackendError if it has none."""
    found = backend(name)
    if not isinstance(found, BackendPlugin):
        raise BackendError(f"backend {name!r} ({found.origin}) has no agent side: its "
                           "plugin object must be a drivers.backends.plugin.BackendPlugin")
    return found


def agent_plugins() -> dict[str, BackendPlugin]:
    """Every backend that an agent can serve, by name."""
    return {n: b for n, b in backends().items() if isinstance(b, BackendPlugin)}
