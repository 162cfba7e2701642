"""The boundary to the ABB YuMi (IRB 14000) controller: motion programs of waypoints.

Why a boundary: the real controller (an IRC5 reached through Robot Web Services) cannot
run in CI, so :class:`~drivers.yumi.backend.YumiBackend` talks to a small client
protocol. :class:`RwsYumiController` implements it with ``abb-motion-program-exec``
(MultiMove: both arms' programs start together, one RAPID task per arm, ``T_ROB_L`` and
``T_ROB_R``) and ``abb-robot-client`` (RWS reads of the TCP positions). The hardware twin's client
(``drivers.yumi.twin_controller``) is the other real one;
:func:`drivers.yumi.controllers.make_controller` picks one from the controller URL.
:class:`drivers.testing.fake_yumi.FakeYumiController` implements it for tests and records
every waypoint; it is a fake on purpose and says so in its name.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, Protocol

from drivers.errors import BackendError

WaypointKind = Literal["move_j", "move_l", "rest"]


@dataclass(frozen=True, slots=True)
class Waypoint:
    """One motion command in the robot base frame (mm); ``rest`` is a joint target."""

    kind: WaypointKind
    xyz_mm: tuple[float, float, float] | None
    speed_mm_s: float
    fine: bool = True
    """Stop exactly at the point (RAPID ``fine``), else fly by (``z10``)."""


@dataclass(frozen=True, slots=True)
class ArmPose:
    """How one arm holds its pusher and where it rests (from the calibration file)."""

    task: str
    """RAPID task of the arm: ``T_ROB_L`` or ``T_ROB_R`` on an IRB 14000."""
    mechunit: str
    """Mechanical unit for RWS reads: ``ROB_L`` or ``ROB_R``."""
    rest_joints_deg: tuple[float, ...]
    """7 joint angles (axis 7, the arm angle, last) of the rest pose out of view."""
    tool_quat_wxyz: tuple[float, ...] = (0.0, 0.0, 1.0, 0.0)
    robconf: tuple[float, ...] = (0.0, 0.0, 0.0, 4.0)
    arm_angle_deg: float = 0.0
    tool_z_mm: float = 0.0


class YumiControllerClient(Protocol):
    def execute(self, programs: Mapping[str, Sequence[Waypoint]]) -> None:
        """Run every arm's program AT THE SAME TIME; return when all have finished."""
        ...

    def tcp_xyz(self) -> dict[str, tuple[float, float, float]]:
        """Current TCP position of every arm, robot base frame, mm."""
        ...

    def close(self) -> None: ...


class RwsYumiController:
    """The real IRB 14000 through Robot Web Services (abb-motion-program-exec)."""

    def __init__(self, base_url: str, arms: Mapping[str, ArmPose], *,
                 username: str = "Default User", password: str = "robotics",
                 http_timeout_s: float = 5.0, motion_timeout_s: float = 60.0) -> None:
        # Lazy: these clients pull in requests/websockets; only a YuMi host needs them.
        from abb_motion_program_exec import abb_motion_program_exec_client as mpe

        self._mpe: Any = mpe
        self._arms = dict(arms)
        self._motion_timeout_s = motion_timeout_s
        self._client: Any = mpe.MotionProgramExecClient(base_url=base_url, username=username,
                                                        password=password)
        # abb-robot-client issues its HTTP requests without a timeout: a controller that
        # accepts the connection and never answers would block the agent for ever.
        session = self._client.abb_client._session
        plain_request = session.request

        def request(method: str, url: str, **kw: Any) -> Any:
            kw.setdefault("timeout", http_timeout_s)
            return plain_request(method, url, **kw)

        session.request = request

    def program(self, arm: str, waypoints: Sequence[Waypoint]) -> Any:
        """The ``MotionProgram`` of one arm (public for tests: its RAPID can be read)."""
        mpe = self._mpe
        pose = self._arms[arm]
        tool = mpe.tooldata(True, mpe.pose([0, 0, pose.tool_z_mm], [1, 0, 0, 0]),
                            mpe.loaddata(0.001, [0, 0, 0.001], [1, 0, 0, 0], 0, 0, 0))
        mp = mpe.MotionProgram(tool=tool)
        extax = [pose.arm_angle_deg, 9e9, 9e9, 9e9, 9e9, 9e9]
        for w in waypoints:
            speed = mpe.speeddata(float(w.speed_mm_s), 500, 5000, 1000)
            zone = mpe.fine if w.fine else mpe.z10
            if w.kind == "rest":
                j = pose.rest_joints_deg
                mp.MoveAbsJ(mpe.jointtarget(list(j[:6]), [j[6], 9e9, 9e9, 9e9, 9e9, 9e9]),
                            speed, zone)
                continue
            if w.xyz_mm is None:
                raise BackendError(f"arm {arm}: a {w.kind} waypoint needs a position")
            target = mpe.robtarget(list(w.xyz_mm), list(pose.tool_quat_wxyz),
                                   mpe.confdata(*pose.robconf), extax)
            (mp.MoveJ if w.kind == "move_j" else mp.MoveL)(target, speed, zone)
        return mp

    def execute(self, programs: Mapping[str, Sequence[Waypoint]]) -> None:
        arms = [a for a in self._arms if a in programs]
        if not arms:
            return
        mps = [self.program(a, programs[a]) for a in arms]
        tasks = [self._arms[a].task for a in arms]
        client = self._client
        try:
            if len(arms) == 1:
                seq = client.execute_motion_program(mps[0], task=tasks[0], wait=False)
            else:
                seq = client.execute_multimove_motion_program(mps, tasks, wait=False)
            deadline = time.monotonic() + self._motion_timeout_s
            while client.is_motion_program_running():  # the library's own wait has no limit
                if time.monotonic() > deadline:
                    client.stop_motion_program()
                    raise BackendError(f"motion did not finish within "
                                       f"{self._motion_timeout_s:g} s; program stopped")
                time.sleep(0.05)
            client.read_motion_program_result_log(seq)  # raises on a controller error
        except BackendError:
            raise
        except Exception as exc:
            raise BackendError(f"YuMi controller refused the motion program: {exc}") from exc

    def tcp_xyz(self) -> dict[str, tuple[float, float, float]]:
        out: dict[str, tuple[float, float, float]] = {}
        try:
            for arm, pose in self._arms.items():
                rt = self._client.abb_client.get_robtarget(mechunit=pose.mechunit)
                out[arm] = (float(rt.trans[0]), float(rt.trans[1]), float(rt.trans[2]))
        except Exception as exc:
            raise BackendError(f"cannot read the arms' positions from the YuMi controller: "
                               f"{exc}") from exc
        return out

    def close(self) -> None:
        with contextlib.suppress(Exception):  # best effort on the way out
            self._client.abb_client.logout()
