"""The YuMi's declaration: what the registry (``testbed.core.backend_registry``) finds of it.

An ABB YuMi (IRB 14000) on an IRC5 controller, reached over Robot Web Services, with
one overhead camera: both arms work over one table (a shared cell), each arm is
calibrated (image-to-table homography), the controller names itself (serial,
RobotWare), the agent locks the robot on that serial, motions can be stopped in flight,
and ``testbed rehearse`` can stand a hardware twin in its place (:class:`YumiTwin`:
``python -m sim_twin.yumi_server``, a PyBullet cell behind the controller's Robot Web
Services and an MJPEG camera). The flags the agent takes for it are written
(``agent_argv``) and read (``add_agent_arguments``, ``backend_kwargs``) here, in one
place.
"""

from __future__ import annotations

import argparse
import os
import secrets
import sys
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, ClassVar
from urllib.parse import urlsplit

from drivers.backends.plugin import BackendPlugin, arm_pairs
from drivers.yumi.yumi_host import YumiHost
from testbed.core.backend_registry import Capabilities, HardwareTwin, HostLike, TwinPlace

if TYPE_CHECKING:
    from drivers.backends.base import HostBackend
    from testbed.core.host_config import HostBase

__all__ = ["BACKEND", "YumiPlugin", "YumiTwin"]

LOOPBACK = ("127.0.0.1", "localhost", "::1")


def deadline_faults(host: HostBase, info: Mapping[str, Any]) -> list[str]:
    """One FAULT when the controller's speed ratio makes a push outlast ``deadline_s``.

    Why: the driver scales its own motion timeout by the speed ratio it reads before every
    start (``motion_timeout_s * 100 / ratio``: drivers/yumi/rws_controller.py), so a push
    at 10 % is given ten times as long; the operator side waits ``deadline_s`` for the
    push's answer and knows nothing of the ratio. At 10 % with the default 20 s the
    operator would fault the host mid-push (docs/rws-checklist.md, "Timeouts at 10 %")."""
    ratio = ((info.get("controller") or {}).get("state") or {}).get("speedratio")
    limit = getattr(host, "motion_timeout_s", None)
    deadline = getattr(host, "deadline_s", None)
    if ratio is None or limit is None or deadline is None or float(ratio) >= 100.0:
        return []
    needed = float(limit) * 100.0 / max(1.0, float(ratio))
    if needed < float(deadline):
        return []
    return [f"the controller's speed ratio is {float(ratio):g} %: the driver waits up to "
            f"{needed:g} s for a motion (motion_timeout_s {float(limit):g} x 100 / "
            f"{float(ratio):g}), the operator only deadline_s {float(deadline):g} s for the "
            f"push: set deadline_s above {needed:g} for runs at this speed, or the ratio to "
            f"100 % (docs/rws-checklist.md, 'Timeouts at 10 %')"]


class YumiTwin(HardwareTwin):
    """A YuMi host's hardware twin: ``python -m sim_twin.yumi_server`` with the host's
    arms, its camera and lab side channel on one port (``port``), the controller's RWS
    1.0 on another (``rws.port``), logging in with the host's login file and logging
    every request it serves. The agent runs ``--backend yumi`` unchanged against it; its
    arms are calibrated against it as a lab's are, and its side channel injects the
    stops a lab meets (``sim_twin.lab_faults``)."""

    ports: ClassVar[tuple[str, ...]] = ("port", "rws.port")
    lab_port: ClassVar[str | None] = "port"
    calibrate: ClassVar[bool] = True
    faults: ClassVar[bool] = True
    request_log: ClassVar[str | None] = "rws.jsonl"

    def identity(self, place: TwinPlace) -> str:
        """The twin controller's serial (an IRB 14000's form): robot locks are keyed on
        it, so each twin of a lab (and of another lab on this machine) has its own,
        stable for its folder."""
        return f"14000-{place.key:06d}"

    def prepare(self, place: TwinPlace) -> None:
        """A fresh controller login (``testbed`` and a random password), mode 0600 from
        its first byte: what a lab puts on its robot host for the real controller."""
        path = place.file("rws.login")
        path.unlink(missing_ok=True)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(f"testbed:{secrets.token_urlsafe(18)}\n")

    def command(self, place: TwinPlace) -> list[str]:
        return [sys.executable, "-m", "sim_twin.yumi_server", "--arms", ",".join(place.arms),
                "--seed", str(place.seed), "--port", "0",
                "--port-file", str(place.port_file("port")),
                "--rws-port-file", str(place.port_file("rws.port")),
                "--rws-credentials", str(place.file("rws.login")),
                "--rws-log", str(place.file("rws.jsonl")),
                "--realtime", f"{place.realtime:g}", "--fps", f"{place.camera_fps:g}",
                "--serial", self.identity(place)]

    def host_fields(self, host: HostLike, place: TwinPlace, ports: Mapping[str, int]
                    ) -> dict[str, Any]:
        """The twin's camera and controller, and the login file (never its text)."""
        return {"camera": f"http://127.0.0.1:{ports['port']}/camera.mjpg",
                "controller_url": f"http://127.0.0.1:{ports['rws.port']}",
                "credentials_file": str(place.file("rws.login"))}


class YumiPlugin(BackendPlugin):
    name: ClassVar[str] = "yumi"
    host_model: ClassVar[type[HostBase]] = YumiHost
    capabilities: ClassVar[Capabilities] = Capabilities(
        calibration=True, camera_frame=True, shared_cell=True, controller=True,
        robot_lock=True, stop=True)
    extra: ClassVar[str | None] = "yumi"
    verify_imports: ClassVar[tuple[str, ...]] = (
        "drivers.yumi.backend", "drivers.cameras.camera", "drivers.yumi.rws_controller",
        "abb_robot_client.rws", "abb_motion_program_exec", "cv2")
    nominal_push_s: ClassVar[float | None] = 8.5
    """A push at the calibration's default speeds (150 mm/s travel, 50 mm/s stroke) is
    the step: 8.5 s (docs/notes/rehearsal.md, "Rehearsal step"; 7.8 s for a 40 mm
    stroke on the real-time twin, docs/notes/yumi-real.md)."""

    # -- the controller's side --------------------------------------------------------
    def hardware_twin(self) -> HardwareTwin:
        return YumiTwin()

    def scripted_teleop(self, host: HostBase) -> bool:
        """Only a hardware twin (its controller on loopback, a rehearsal) carries the
        expert's action; a lab's YuMi is teleoperated by people."""
        url = str(getattr(host, "controller_url", ""))
        return (urlsplit(url).hostname or "") in LOOPBACK

    def controller_report(self, host: HostBase, info: Mapping[str, Any]
                          ) -> tuple[list[str], list[str]]:
        """The report of ``drivers/yumi/check_report.py``; an arm in the camera's view
        first (``describe`` is read-only: ``drivers/yumi/backend.py`` ``in_view_faults``)."""
        from drivers.yumi.backend import in_view_faults
        from drivers.yumi.check_report import controller_report

        lines, faults = controller_report(host.name, info)
        return lines, [*in_view_faults(info), *faults, *deadline_faults(host, info)]

    def default_table_box(self, arm: str, calibration: Mapping[str, Any] | None = None
                          ) -> tuple[float, float, float, float] | None:
        """The shipped layout's table box of the arm's side (its file's ``task``, else its
        name): ``drivers/yumi/arm_calibration.py``'s ``default_table_box``, the box the
        agent drives an arm being calibrated in when its file has none."""
        from drivers.yumi.arm_calibration import default_table_box

        task = (calibration or {}).get("task")
        return default_table_box(arm, task if isinstance(task, str) else None)

    def layout_report(self, host: HostBase, calibrations: Mapping[str, Mapping[str, Any]],
                      info: Mapping[str, Any] | None = None) -> tuple[list[str], list[str]]:
        """The arms' layout through the IRB 14000's kinematics, as ``testbed check``
        words it (``drivers/yumi/check_report.py``), from calibration files."""
        from drivers.yumi.check_report import layout_report

        info = dict(info or {})
        info["layout"] = {arm: dict(cal) for arm, cal in calibrations.items()}
        return layout_report(info.get("controller") or {}, info)

    def agent_argv(self, host: HostBase) -> list[str]:
        argv: list[str] = []
        if (camera := getattr(host, "camera", None)) is not None:
            argv += ["--camera", str(camera)]
        if (cam_settings := getattr(host, "camera_settings", None)) is not None:
            argv += ["--camera-settings", cam_settings.model_dump_json(exclude_none=True)]
        if (url := getattr(host, "controller_url", None)) is not None:
            argv += ["--controller-url", str(url)]
        if (creds := getattr(host, "credentials_file", None)) is not None:
            argv += ["--credentials-file", str(creds)]
        if (limit := getattr(host, "motion_timeout_s", None)) is not None:
            argv += ["--motion-timeout", f"{limit:g}"]
        if (locks := getattr(host, "lock_dir", None)) is not None:
            argv += ["--lock-dir", str(locks)]
        for a in host.arms:
            if a.crop is not None:
                argv += ["--crop", f"{a.name}=" + ",".join(str(v) for v in a.crop)]
            if a.calibration is not None:
                argv += ["--calibration", f"{a.name}={a.calibration}"]
        return argv

    # -- the agent's side -------------------------------------------------------------
    def add_agent_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--camera", default=None, help="yumi: device index or video file")
        parser.add_argument("--controller-url", default=None,
                            help="yumi: RWS URL of the controller")
        parser.add_argument("--crop", action="append", default=[], metavar="ARM=x0,y0,x1,y1")
        parser.add_argument("--calibration", action="append", default=[], metavar="ARM=FILE")
        parser.add_argument("--credentials-file", default=None, metavar="FILE",
                            help="yumi: the controller's login, one line USER:PASSWORD, "
                                 "mode 0600")
        parser.add_argument("--motion-timeout", type=float, default=None, metavar="S",
                            help="yumi: stop a motion program that runs longer than S s")
        parser.add_argument("--camera-settings", default=None, metavar="JSON",
                            help="yumi: the camera's settings, a JSON object of width, "
                                 "height, fourcc, fps, exposure, white_balance, focus (set "
                                 "on a V4L2 camera when it opens, and read back)")

    def backend_kwargs(self, args: argparse.Namespace) -> dict[str, Any] | str:
        """``credentials_file``, ``motion_timeout_s`` and ``camera_settings`` only when
        given (the camera validates the settings' JSON text itself)."""
        crops: dict[str, tuple[int, int, int, int]] = {}
        pairs = arm_pairs(args.crop, "--crop")
        if isinstance(pairs, str):
            return pairs
        for arm, box in pairs.items():
            try:
                x0, y0, x1, y1 = (int(v) for v in box.split(","))
            except ValueError:
                return f"--crop {arm}=... needs four integers"
            crops[arm] = (x0, y0, x1, y1)
        calibrations = arm_pairs(args.calibration, "--calibration")
        if isinstance(calibrations, str):
            return calibrations
        kwargs: dict[str, Any] = dict(crops=crops, calibrations=calibrations,
                                      camera=args.camera, controller_url=args.controller_url)
        if args.credentials_file is not None:
            kwargs["credentials_file"] = args.credentials_file
        if args.motion_timeout is not None:
            kwargs["motion_timeout_s"] = args.motion_timeout
        if args.camera_settings is not None:
            kwargs["camera_settings"] = args.camera_settings
        from drivers.hostlock import default_lock_dir  # the zones proof: beside the lock

        kwargs["zones_state_dir"] = getattr(args, "lock_dir", None) or default_lock_dir()
        return kwargs

    def make_backend(self, *, arms: Sequence[str], mirror: Sequence[bool], seed: int,
                     calibrating: Sequence[str] = (), **kwargs: Any) -> HostBackend:
        from drivers.yumi.backend import build_yumi_backend

        return build_yumi_backend(
            arms, mirror, kwargs.get("crops") or {}, kwargs.get("calibrations") or {},
            kwargs.get("camera"), kwargs.get("controller_url"), seed,
            calibrating=tuple(calibrating), credentials_file=kwargs.get("credentials_file"),
            motion_timeout_s=kwargs.get("motion_timeout_s"),
            camera_settings=kwargs.get("camera_settings"),
            zones_state_dir=kwargs.get("zones_state_dir"))

    def controller_info(self, args: argparse.Namespace) -> dict[str, str] | None:
        """Serial, RobotWare and system: one read-only login, before the lock."""
        if not args.controller_url:
            return None
        from drivers.yumi.rws_controller import controller_info

        return controller_info(args.controller_url, args.credentials_file)

    def controller_address(self, args: argparse.Namespace) -> str | None:
        return args.controller_url

    def robot_identity(self, args: argparse.Namespace,
                       controller: Mapping[str, str] | None) -> str | None:
        """The controller as it names itself (``"IRC5 <serial>"``), else its URL in one
        spelling (two spellings of one address are one robot)."""
        if not args.controller_url:
            return None
        from drivers.hostlock import normalise_url
        from drivers.yumi.rws_controller import robot_identity

        return robot_identity(controller) or normalise_url(args.controller_url)


BACKEND = YumiPlugin()
