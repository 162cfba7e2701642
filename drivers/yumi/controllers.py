"""The YuMi controller factory: the client that a controller URL names.

Why a module of its own: the clients (:mod:`drivers.yumi.yumi_controller`, the real
controller through Robot Web Services; :mod:`drivers.yumi.twin_controller`, the hardware
twin) and the seam they share stay free of each other -- the twin client imports the seam,
nothing imports back -- while the one place that knows both is this factory. The backend
(:mod:`drivers.yumi.backend`) calls it and never knows which client it drives.
"""

from __future__ import annotations

from collections.abc import Mapping

from drivers.errors import BackendError
from drivers.yumi.twin_controller import TwinControllerClient
from drivers.yumi.yumi_controller import ArmPose, RwsYumiController, YumiControllerClient

__all__ = ["make_controller"]


def make_controller(url: str, poses: Mapping[str, ArmPose | None], *,
                    field_name: str = "controller_url") -> YumiControllerClient:
    """The controller client that ``url`` names: ``twin+http://HOST:PORT`` the hardware
    twin (:class:`~drivers.yumi.twin_controller.TwinControllerClient`), ``http(s)://``
    the real controller's Robot Web Services. Here, so that ``backend.py`` never knows
    which one it drives. ``poses``: every arm (config order) with its pose from the
    calibration file; the real controller needs each arm's rest pose, the twin knows its
    own."""
    low = url.strip().lower()
    if low.startswith("twin+http://"):
        return TwinControllerClient(url.strip(), list(poses))
    if low.startswith(("http://", "https://")):
        if missing := [arm for arm, pose in poses.items() if pose is None]:
            raise BackendError(
                f"arm {missing[0]}: its calibration file has no 'rest_joints_deg' (7 angles): "
                f"the YuMi controller (RWS) needs every arm's rest pose, also while "
                f"calibrating" + (f" (arms without one: {missing})" if len(missing) > 1 else ""))
        return RwsYumiController(url.strip(), {a: p for a, p in poses.items() if p is not None})
    raise BackendError(f"{field_name}: {url!r} is not a controller URL; expected http(s)://HOST "
                       f"(the YuMi's Robot Web Services) or twin+http://HOST:PORT (the "
                       f"hardware twin)")
