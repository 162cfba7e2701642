"""Host backends: what an agent drives (a twin cell, an ABB YuMi, any future robot).

Why a lazy factory here: the agent chooses its backend from the command line, and a
backend's heavy imports (pybullet for the twin, the ABB clients for the YuMi) must
happen only in the agent that needs them, after the agent has claimed its stdout.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from typing import Any

from drivers.backends.base import ArmOutcome, ArmView, HostBackend

__all__ = ["ArmOutcome", "ArmView", "HostBackend", "make_backend"]


def make_backend(kind: str, *, arms: Sequence[str], mirror: Sequence[bool], seed: int,
                 physics: bool = True, crops: Mapping[str, tuple[int, int, int, int]] | None = None,
                 calibrations: Mapping[str, str] | None = None, camera: str | None = None,
                 controller_url: str | None = None, calibrating: Collection[str] = (),
                 credentials_file: str | None = None, motion_timeout_s: float | None = None,
                 camera_settings: Mapping[str, Any] | str | None = None) -> HostBackend:
    """The agent's backend. ``calibrating``: yumi arms being calibrated (``--calibrate``):
    they start with a provisional calibration; a twin has nothing to calibrate.
    ``credentials_file`` and ``motion_timeout_s``: the YuMi controller's login file and
    motion limit; ``camera_settings``: its camera's (a twin has none of them)."""
    if kind == "twin":
        from drivers.backends.twin import CannedTwinBackend, TwinBackend

        if not physics:
            return CannedTwinBackend(seed, arms, mirror)
        return TwinBackend(seed, arms, mirror)
    if kind == "yumi":
        from drivers.yumi.backend import build_yumi_backend

        return build_yumi_backend(arms, mirror, crops or {}, calibrations or {}, camera,
                                  controller_url, seed, calibrating=tuple(calibrating),
                                  credentials_file=credentials_file,
                                  motion_timeout_s=motion_timeout_s,
                                  camera_settings=camera_settings)
    raise ValueError(f"unknown backend {kind!r}; expected 'twin' or 'yumi'")
