"""The boundary to the ABB YuMi (IRB 14000) controller: motion programs of waypoints.

Why a boundary: the real controller (an IRC5 reached through Robot Web Services) cannot
run in CI, so :class:`~drivers.yumi.backend.YumiBackend` talks to a small client
protocol. :class:`RwsYumiController` implements it: ``abb-motion-program-exec`` builds
each arm's program bytes, and a client of our own on ``abb-robot-client`` (RWS) uploads
each to ITS task's file (``testbed_T_ROB_L.bin``, ``testbed_T_ROB_R.bin``: the library's
own naming would put both in one), starts both tasks together (MultiMove, one RAPID task
per arm) and reads the result our RAPID (robot/rapid/) writes to the event log. The
hardware twin's client (``drivers.yumi.twin_controller``) is the other real one;
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


PROGRAM_FILE = "testbed_{task}.bin"
"""The RAM-disk file each task's RAPID reads (``tb_name`` in robot/rapid/TestbedTask_*.mod):
fixed per task, so the two arms' programs never share a file (the library's own naming
puts ``T_ROB_L``'s and ``T_ROB_R``'s in one)."""
DONE, FAILED = "Testbed Motion Done", "Testbed Motion Failed"
"""``args[0]`` of the ``ErrWrite`` entries our RAPID writes (80003 done, 80001 refused)."""


def program_file(task: str) -> str:
    """The file name (on the controller's RAM disk) that task ``task`` reads."""
    return PROGRAM_FILE.format(task=task)


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def _entry_text(e: Any) -> str:
    """One line naming an event log entry: code, title and what it says."""
    args = [a for a in (getattr(e, "args", None) or []) if str(a).strip()]
    if len(args) > 1 and str(args[0]).lower() == str(e.title).lower():  # an ErrWrite's lines
        detail = "; ".join(str(a) for a in args[1:])
    else:
        detail = getattr(e, "desc", "") or "; ".join(str(a) for a in args)
    return _one_line(f"event log {e.code} {e.title!r}: {detail}")


def _since(log: Sequence[Any], prev: int | None) -> list[Any]:
    """The entries of ``log`` (newest first) written after ``prev``, oldest first
    (RobotWare's sequence numbers are a uint16: they wrap)."""
    out = []
    for e in log:
        if prev is None or e.seqnum > prev or (prev > 61440 and e.seqnum < 4096):
            out.append(e)
        else:
            break
    return out[::-1]


def check_result(entries: Sequence[Any], tasks: Sequence[str], seqno: int) -> None:
    """Raise :class:`BackendError` unless every task of ``tasks`` reported our RAPID's
    "done" for program ``seqno`` and no error (type 3) was logged (``entries``: oldest
    first, since the start)."""
    errors = [e for e in entries if e.msgtype >= 3]
    if errors:
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        raise BackendError(f"YuMi controller: {_entry_text(errors[0])}{more}")
    done = {str(e.args[1]) for e in entries
            if e.code == 80003 and len(e.args) >= 3 and str(e.args[0]) == DONE
            and str(e.args[2]) == f"seqno {seqno}"}
    if missing := [t for t in tasks if t not in done]:
        raise BackendError(f"YuMi controller: task(s) {', '.join(missing)} ended without "
                           f"the event log entry {DONE!r} for program {seqno}: is the "
                           f"testbed RAPID (robot/rapid/) loaded? See robot/README.md")


class RwsYumiController:
    """The real IRB 14000 through Robot Web Services: ``abb_motion_program_exec`` builds
    each arm's program bytes, our RAPID (robot/rapid/) runs them, and this client (on
    ``abb_robot_client.rws.RWS``) uploads, starts, waits and reads the result."""

    def __init__(self, base_url: str, arms: Mapping[str, ArmPose], *,
                 username: str = "Default User", password: str = "robotics",
                 http_timeout_s: float = 5.0, motion_timeout_s: float = 60.0) -> None:
        # Lazy: these clients pull in requests/websockets; only a YuMi host needs them.
        from abb_motion_program_exec import abb_motion_program_exec_client as mpe
        from abb_robot_client.rws import RWS

        self._mpe: Any = mpe
        self._arms = dict(arms)
        self._motion_timeout_s = motion_timeout_s
        self._seqno = 0
        self._rws: Any = RWS(base_url, username, password)
        # abb-robot-client issues its HTTP requests without a timeout: a controller that
        # accepts the connection and never answers would block the agent for ever.
        session = self._rws._session
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
        mps = {self._arms[a].task: self.program(a, programs[a]) for a in arms}
        self._seqno = self._seqno % 60000 + 1  # float32-exact, and new for every step
        seqno = self._seqno
        try:
            prev = self._start(mps, seqno)
            self._wait()
            entries = _since(self._rws.read_event_log(), prev)
        except BackendError:
            raise
        except Exception as exc:
            raise BackendError(f"YuMi controller refused the motion program: "
                               f"{_one_line(exc)}") from exc
        check_result(entries, list(mps), seqno)

    def _start(self, mps: Mapping[str, Any], seqno: int) -> int | None:
        """Upload every task's program to ITS file and start those tasks together; the
        newest event log entry before the start (None: an empty log)."""
        rws = self._rws
        state = rws.get_execution_state().ctrlexecstate
        if state != "stopped":
            raise BackendError(f"YuMi controller: RAPID is {state} (started elsewhere?); "
                               f"the motion program was not started")
        ctrl = rws.get_controller_state()
        if ctrl != "motoron":
            raise BackendError(f"YuMi controller: the controller state is {ctrl}, not "
                               f"motoron; the motion program was not started")
        log = rws.read_event_log()
        prev = log[0].seqnum if log else None
        rws.resetpp()
        ramdisk = rws.get_ramdisk_path()
        for task, mp in mps.items():
            rws.upload_file(f"{ramdisk}/{program_file(task)}", mp.get_program_bytes(seqno))
        rws.start(cycle="once", tasks=list(mps))
        return prev

    def _wait(self) -> None:
        deadline = time.monotonic() + self._motion_timeout_s
        while self._rws.get_execution_state().ctrlexecstate == "running":
            if time.monotonic() > deadline:
                self._rws.stop()
                raise BackendError(f"motion did not finish within "
                                   f"{self._motion_timeout_s:g} s; program stopped")
            time.sleep(0.05)

    def tcp_xyz(self) -> dict[str, tuple[float, float, float]]:
        out: dict[str, tuple[float, float, float]] = {}
        try:
            for arm, pose in self._arms.items():
                rt = self._rws.get_robtarget(mechunit=pose.mechunit)
                out[arm] = (float(rt.trans[0]), float(rt.trans[1]), float(rt.trans[2]))
        except Exception as exc:
            raise BackendError(f"cannot read the arms' positions from the YuMi controller: "
                               f"{exc}") from exc
        return out

    def close(self) -> None:
        with contextlib.suppress(Exception):  # best effort on the way out
            self._rws.logout()
