"""The seam to the ABB YuMi (IRB 14000) controller: motion programs of waypoints.

Why a seam: the real controller (an IRC5 reached through Robot Web Services) cannot run
in CI, so :class:`~drivers.yumi.backend.YumiBackend` talks to a small client protocol,
:class:`YumiControllerClient`. One real client implements it,
:class:`~drivers.yumi.rws_controller.RwsYumiController` (the controller's RWS, and the
hardware twin's, which speaks the same RWS 1.0); :func:`drivers.yumi.controllers.
make_controller` builds it from the controller URL. :class:`drivers.testing.fake_yumi.
FakeYumiController` implements the seam for the backend's unit tests and records every
waypoint; it is a fake on purpose and says so in its name. This module also holds what
the client and our RAPID (robot/rapid/) agree on: each task's program file and the
event-log entries that report a program's end.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, Protocol

from drivers.errors import BackendError
from drivers.yumi.controller_state import entry_text

WaypointKind = Literal["move_j", "move_l", "abs_j", "rest"]
"""``move_l``: a straight line to ``xyz_mm`` (MoveL); ``abs_j``: a joint move to
``joints_deg`` (MoveAbsJ); ``rest``: a joint move to the arm's rest joints (MoveAbsJ).
The driver's paths (``drivers/yumi/paths.py``) use only these three, so every path it
sends is one ``testbed check`` sweeps; ``move_j`` (MoveJ to a robtarget: the controller
picks the configuration) stays for the client's own tests and is never planned."""


@dataclass(frozen=True, slots=True)
class Waypoint:
    """One motion command in the robot's world frame (wobj0), mm, or a joint target."""

    kind: WaypointKind
    xyz_mm: tuple[float, float, float] | None
    speed_mm_s: float
    fine: bool = True
    """Stop exactly at the point (RAPID ``fine``), else fly by (``z10``)."""
    joints_deg: tuple[float, ...] | None = None
    """An ``abs_j``'s joint target: 7 angles in ABB's order (axes 1-6, then axis 7)."""


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
    arm_angle_deg: float | None = None
    """ABB's arm angle its targets are solved at (the calibration's ``arm_angle_deg``);
    None: the driver's default for the side (``drivers/yumi/arm_calibration.py``)."""
    tool_z_mm: float | None = None
    """The pusher's length (the calibration's ``tool_z_mm``); None: not known, and the
    controller client refuses to send a program (never the flange by default)."""


class YumiControllerClient(Protocol):
    def execute(self, programs: Mapping[str, Sequence[Waypoint]]) -> None:
        """Run every arm's program AT THE SAME TIME; return when all have finished."""
        ...

    def tcp_xyz(self) -> dict[str, tuple[float, float, float]]:
        """Current TCP (the pusher's tip) of every arm, in the frame the waypoints use
        (``wobj0``), mm."""
        ...

    def joints(self) -> dict[str, tuple[float, ...]]:
        """Current joints of every arm as the controller reports them: 7 angles in
        ABB's order (axes 1-6, then axis 7), degrees. The driver judges where an arm
        is from these (``drivers/yumi/arm_place.py``), never from a model's tip."""
        ...

    def stop(self) -> None:
        """Stop a program that is running, now (from another thread than ``execute``'s,
        which then raises a :class:`BackendError`); returns within a second."""
        ...

    def describe(self) -> dict[str, Any]:
        """What ``testbed check`` prints of the controller (a
        :class:`~drivers.yumi.controller_state.ControllerReport` as a dict)."""
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
        raise BackendError(f"YuMi controller: {entry_text(errors[0])}{more}")
    done = {str(e.args[1]) for e in entries
            if e.code == 80003 and len(e.args) >= 3 and str(e.args[0]) == DONE
            and str(e.args[2]) == f"seqno {seqno}"}
    if missing := [t for t in tasks if t not in done]:
        raise BackendError(f"YuMi controller: task(s) {', '.join(missing)} ended without "
                           f"the event log entry {DONE!r} for program {seqno}: is the "
                           f"testbed RAPID (robot/rapid/) loaded? See robot/README.md")


