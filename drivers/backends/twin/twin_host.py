"""A twin host's config: the fields the twin backend adds to every host's.

Why here: a backend's schema lives with the backend (``testbed.core.host_config`` holds
what every host has); the twin plugin declares this model as its hosts'.
"""

from __future__ import annotations

from typing import Literal

from testbed.core.host_config import HostBase

__all__ = ["TwinHost"]


class TwinHost(HostBase):
    """A PyBullet twin cell (``drivers/backends/twin/twin_backend.py``)."""

    backend: Literal["twin"] = "twin"
    seed: int | None = None
    """The cell's world seed (default: derived from the trial seed)."""
    physics: bool = True
    """False runs the agent's no-physics mode (canned images; benchmarks)."""
