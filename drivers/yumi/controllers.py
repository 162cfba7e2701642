"""The YuMi controller factory: the client that a host's controller settings name.

Why a module of its own: the backend (:mod:`drivers.yumi.backend`) builds its controller
here and never imports the ABB libraries; this is also where the controller URL, the
login (:mod:`drivers.yumi.credentials`) and the motion timeout meet. There is one client,
:class:`~drivers.yumi.rws_controller.RwsYumiController`, for a lab's IRC5 and for the
hardware twin alike: both speak Robot Web Services 1.0.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

from drivers.errors import BackendError
from drivers.yumi.credentials import read_login
from drivers.yumi.rws_controller import RwsYumiController
from drivers.yumi.yumi_controller import ArmPose, YumiControllerClient

__all__ = ["make_controller"]


def make_controller(url: str, poses: Mapping[str, ArmPose | None], *,
                    credentials_file: str | None = None, motion_timeout_s: float = 15.0,
                    field_name: str = "controller_url",
                    zones_state_dir: str | os.PathLike[str] | None = None
                    ) -> YumiControllerClient:
    """The controller client for ``url`` (``http(s)://HOST[:PORT]``, the controller's Robot
    Web Services). ``poses``: every arm (config order) with its pose from the calibration
    file; the controller needs each arm's rest pose, also while calibrating.
    ``credentials_file``: the host's ``USER:PASSWORD`` file (required: None is refused by
    the controller client; ``"factory-default"`` names the factory login, twin only).
    ``zones_state_dir``: where the zones proof is recorded for the next agent (the robot
    lock's folder; :mod:`drivers.yumi.zones_proof`)."""
    low = url.strip().lower()
    if not low.startswith(("http://", "https://")):
        raise BackendError(f"{field_name}: {url!r} is not a controller URL; expected "
                           f"http(s)://HOST[:PORT] (the YuMi's Robot Web Services)")
    if missing := [arm for arm, pose in poses.items() if pose is None]:
        raise BackendError(
            f"arm {missing[0]}: its calibration file has no 'rest_joints_deg' (7 angles): "
            f"the YuMi controller needs every arm's rest pose, also while calibrating"
            + (f" (arms without one: {missing})" if len(missing) > 1 else ""))
    login = read_login(credentials_file) if credentials_file else None
    return RwsYumiController(url.strip().rstrip("/"),
                             {a: p for a, p in poses.items() if p is not None},
                             login=login, motion_timeout_s=motion_timeout_s,
                             zones_state_dir=zones_state_dir)
