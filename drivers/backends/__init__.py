"""Host backends: what an agent drives (a twin cell, an ABB YuMi, any future robot).

Each backend is a plugin (``drivers/backends/plugin.py``, found by the registry in
``testbed.core.backend_registry``): its folder holds its host model, its ``HostBackend`` and
its declaration (the twin: ``drivers/backends/twin/``; the YuMi: ``drivers/yumi/``).
A backend's heavy imports (pybullet for the twin, the ABB clients for the YuMi) happen
only in the agent that needs them, after the agent has claimed its stdout.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from drivers.backends.base import ArmOutcome, ArmView, HostBackend

__all__ = ["ArmOutcome", "ArmView", "HostBackend", "make_backend"]


def make_backend(kind: str, *, arms: Sequence[str], mirror: Sequence[bool], seed: int,
                 calibrating: Sequence[str] = (), **kwargs: Any) -> HostBackend:
    """The backend ``kind``'s ``HostBackend``, built by its plugin
    (``drivers.backends.plugin.BackendPlugin.make_backend``): ``kwargs`` are the
    backend's own (a YuMi's ``camera``, ``controller_url``, ``crops``, ...)."""
    from drivers.backends.plugin import agent_plugin

    return agent_plugin(kind).make_backend(arms=arms, mirror=mirror, seed=seed,
                                           calibrating=tuple(calibrating), **kwargs)
