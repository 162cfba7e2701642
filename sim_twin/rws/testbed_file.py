"""Our RAPID's reading of a program file, played line for line by the twin: ``tb_run``,
``tb_header``, ``tb_command``, ``tb_target``, ``tb_speeddata``, ``tb_zonedata``, ``tb_num``
of robot/rapid/TestbedMotion.mod, with the same checks in the same order, the same
reasons and details and the same byte offset.

Why a reading of its own, beside :func:`sim_twin.rws.motion_program.decode_program` (the
library's RAPID): our RAPID refuses a file at the FIRST field that fails a check, while it
reads it. A decoder that reads the whole file and then checks it names another field than
the robot does whenever a file has two faults (a target below the table before a file cut
short, a NaN after a speed above its cap), and a hostile file has as many as it likes.
tests/sim_twin/test_rws_hostile_files.py compares the two sides field by field.

The limits (issue 43; robot/README.md, "The limits a file cannot pass"): every field a
file can set is held to one of the controller's: speeds above 0 and at most the task
module's caps (:class:`Limits`: ``tb_v_tcp_max``, ``tb_v_ori_max``, ``tb_v_reax_max``) or
:data:`V_LEAX_MAX`; each zonedata field from 0 to z10's (:data:`ZONE_MAX`); waits from 0 to
:data:`WAIT_MAX`; the work object wobj0's (:data:`WOBJ_REFUSED` otherwise); no number that
is not finite (:data:`NOT_FINITE`); and, as before, the tool frame, the command count, the
commands and the floor.

``NumToStr(v, d)`` is played as ``v`` rounded to ``d`` decimals, trailing zeros left off
(assumed, as :func:`frame_text`: docs/rws-checklist.md).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

from sim_twin.rws.irc5 import RapidError
from sim_twin.rws.motion_program import (
    ERRWRITE_ERROR,
    FILE_VERSION,
    Command,
    ConfData,
    EgmConfig,
    JointTarget,
    LoadData,
    MotionProgramFile,
    MoveAbsJ,
    MoveJ,
    MoveL,
    Pose,
    RobTarget,
    SpeedData,
    ToolData,
    WaitTime,
    WobjData,
    ZoneData,
)
from sim_twin.rws.rapid_data import format_number

DONE, FAILED = "Testbed Motion Done", "Testbed Motion Failed"
"""The headers (``args[0]``) of our RAPID's event log entries; the driver reads them."""
MAX_COMMANDS = 64
"""The size of our RAPID's command arrays (``TB_MAX_CMDS`` in TestbedMotion.mod)."""
TOOL_MM, TOOL_DEG = 1.0, 0.5
"""``TB_TOOL_MM``, ``TB_TOOL_DEG``: how far a file's tool frame may be from
``tool_pusher``'s (translation, mm; rotation, deg) before our RAPID refuses it."""
TOOL_DIFFERS = "Tool frame differs from tool_pusher"
"""``TB_TOOL_DIFFERS``: the reason line (``args[1]``) of that refusal."""
V_TCP_MAX, V_ORI_MAX, V_REAX_MAX = 150.0, 100.0, 100.0
"""``tb_v_tcp_max`` (mm/s), ``tb_v_ori_max`` (deg/s), ``tb_v_reax_max`` (deg/s, axis 7) as
the task modules ship them (the lab sets its own; the calibration's default
``max_speed_mm_s`` and the driver's v_ori and v_reax pass)."""
V_LEAX_MAX = 1000.0
"""``TB_V_LEAX_MAX`` (mm/s): the YuMi has no linear external axis; the driver writes 1000."""
WAIT_MAX = 2.0
"""``TB_WAIT_MAX`` (s): the driver sends only ``WaitTime 0``."""
ZONE_MAX = {"pzone_tcp": ("TB_ZONE_MAX", 10.0), "pzone_ori": ("TB_PZONE_ORI_MAX", 15.0),
            "pzone_eax": ("TB_PZONE_EAX_MAX", 15.0), "zone_ori": ("TB_ZONE_ORI_MAX", 1.5),
            "zone_leax": ("TB_ZONE_LEAX_MAX", 15.0), "zone_reax": ("TB_ZONE_REAX_MAX", 1.5)}
"""Each zonedata field -> (its cap's CONST in TestbedMotion, the cap): z10's values."""
SPEED_OVER = "Speed above the cell's limit"
WAIT_OVER = "Wait above the limit"
ZONE_OVER = "Corner zone above the limit"
WOBJ_REFUSED = "Work object not supported"
NOT_FINITE = "Invalid number"
"""``TB_SPEED_OVER``, ``TB_WAIT_OVER``, ``TB_ZONE_OVER``, ``TB_WOBJ_REFUSED``,
``TB_NOT_FINITE``: the reasons of the issue-43 refusals."""
REASONS = ("Motion program file not found", "Motion program file truncated",
           "Invalid bool in motion program", "Invalid string in motion program",
           "Invalid motion program file version", "Stationary tool not supported",
           TOOL_DIFFERS, "Moving work object not supported", WOBJ_REFUSED,
           "EGM not supported", "Too many commands", "Unsupported command",
           "Invalid motion program command", "Target below the table", "Invalid speed",
           SPEED_OVER, "Invalid zone", ZONE_OVER, "Invalid WaitTime", WAIT_OVER, NOT_FINITE)
"""Every reason our RAPID refuses a file with (tests/test_rapid.py checks the module's)."""
STRING_BYTES = 32
IDENTITY = Pose((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
_F32 = struct.Struct("<f")


@dataclass(frozen=True)
class Limits:
    """What one task's module sets: ``tb_floor_z`` and the speed caps."""

    floor_z: float = 0.0
    v_tcp_max: float = V_TCP_MAX
    v_ori_max: float = V_ORI_MAX
    v_reax_max: float = V_REAX_MAX


def num_to_str(v: float, dec: int) -> str:
    """RAPID's ``NumToStr(v, dec)`` as the twin plays it (the module's docstring)."""
    return format_number(round(float(v), dec) + 0.0)


def clip(s: str) -> str:
    """``tb_clip``: an event log line (and a RAPID string) holds at most 80 characters."""
    return s[:80]


def refusal(reason: str, detail: str, last: str = "") -> RapidError:
    """Our RAPID's refusal (``ErrWrite`` 80001): the reason, the file (filled in by the
    hook), the detail, the last line (``at byte <n>``, or ``tool_pusher``'s frame)."""
    return RapidError(ERRWRITE_ERROR, FAILED, desc=f"{reason}: {detail}",
                      args=(FAILED, reason, "", detail, last))


def angle_deg(a: Sequence[float], b: Sequence[float]) -> float:
    """``tb_angle``: the angle between two orientations (quaternions, either sign),
    ``2 acos(|a.b|)`` computed as ``4 asin(|a - s b| / 2)`` (``s`` the sign of ``a.b``) on
    the normalised quaternions; 180 for a zero one."""
    na, nb = math.sqrt(sum(x * x for x in a)), math.sqrt(sum(x * x for x in b))
    if na == 0.0 or nb == 0.0:
        return 180.0
    s = -1.0 if sum(x * y for x, y in zip(a, b, strict=True)) < 0.0 else 1.0
    d = math.sqrt(sum((x / na - s * y / nb) ** 2 for x, y in zip(a, b, strict=True))) / 2.0
    return math.degrees(4.0 * math.asin(min(d, 1.0)))


def frame_text(f: Pose) -> str:
    """``tb_frame``: ``[[x,y,z],[q1,q2,q3,q4]]``, mm to 0.1 and q to 0.0001."""
    return (f"[[{','.join(num_to_str(v, 1) for v in f.trans)}],"
            f"[{','.join(num_to_str(v, 4) for v in f.rot)}]]")


def tool_differs(file: Pose, held: Pose) -> RapidError | None:
    """``tb_tool``: the refusal of a file frame more than :data:`TOOL_MM` or
    :data:`TOOL_DEG` from ``tool_pusher``'s, else None."""
    if math.dist(file.trans, held.trans) <= TOOL_MM and angle_deg(file.rot, held.rot) <= TOOL_DEG:
        return None
    return refusal(TOOL_DIFFERS, clip(f"file {frame_text(file)}"),
                   clip(f"tool_pusher {frame_text(held)}"))


class _Refused(Exception):
    """A refusal raised while reading (carried out as its :class:`RapidError`)."""

    def __init__(self, error: RapidError) -> None:
        super().__init__(error.desc)
        self.error = error


class _TbReader:
    """The file as ``TestbedMotion`` reads it: ``pos`` is ``tb_pos``, ``what`` ``tb_what``."""

    def __init__(self, data: bytes, held: ToolData, limits: Limits) -> None:
        self.data, self.held, self.limits = bytes(data), held, limits
        self.pos, self.what = 0, "version"

    # tb_fail, with the handler's last line: "at byte <tb_pos>" unless given
    def fail(self, reason: str, detail: str, last: str = "") -> _Refused:
        return _Refused(refusal(reason, detail, last or f"at byte {self.pos}"))

    def _raw(self, n: int) -> bytes:
        """``ReadRawBytes``: at the file's end, ``ERR_RANYBIN_EOF`` (tb_run's handler)."""
        if self.pos + n > len(self.data):
            raise self.fail("Motion program file truncated", "the file ends inside a value")
        return self.data[self.pos:self.pos + n]

    def num(self) -> float:
        raw = self._raw(4)
        if raw[3] % 128 == 127 and raw[2] >= 128:  # exponent all ones: inf or NaN
            raise self.fail(NOT_FINITE, f"{self.what}: not a finite number")
        self.pos += 4
        return float(_F32.unpack(raw)[0])

    def nums(self, n: int) -> tuple[float, ...]:
        return tuple(self.num() for _ in range(n))

    def flag(self, what: str) -> bool:
        v = self.num()
        if v not in (0.0, 1.0):
            raise self.fail("Invalid bool in motion program", f"{what} is {num_to_str(v, 3)}")
        return v == 1.0

    def string(self, what: str) -> str:
        n = self.num()
        if n < 0 or n > STRING_BYTES or n != math.floor(n + 0.5):
            raise self.fail("Invalid string in motion program", f"{what} length {num_to_str(n, 0)}")
        raw = self._raw(STRING_BYTES)
        self.pos += STRING_BYTES
        return raw[:int(n)].decode("latin-1")

    def pose(self) -> Pose:
        x, y, z, q1, q2, q3, q4 = self.nums(7)
        return Pose((x, y, z), (q1, q2, q3, q4))

    def load(self) -> LoadData:
        m, cx, cy, cz, a1, a2, a3, a4, ix, iy, iz = self.nums(11)
        return LoadData(m, (cx, cy, cz), (a1, a2, a3, a4), ix, iy, iz)

    # --- tb_header ---------------------------------------------------------------------------
    def header(self) -> tuple[int, LoadData, str, int]:
        """The version, the grip load, the timestamp and the seqno, every header check
        passed."""
        version = self.num()
        if version != FILE_VERSION:
            raise self.fail("Invalid motion program file version",
                            f"{num_to_str(version, 0)} (expected {FILE_VERSION})")
        self.what = "tooldata"
        if not self.flag("tool robhold"):
            raise self.fail("Stationary tool not supported", "tool robhold")
        differs = tool_differs(self.pose(), self.held.tframe)
        if differs is not None:
            raise _Refused(differs)
        self.load()
        self.what = "wobjdata"
        robhold, ufprog = self.flag("wobj robhold"), self.flag("wobj ufprog")
        ufmec = self.string("wobj ufmec")
        frames = {"uframe": self.pose(), "oframe": self.pose()}
        if robhold or not ufprog or ufmec != "":
            raise self.fail("Moving work object not supported", "robhold, ufprog or ufmec")
        for name, frame in frames.items():  # tb_identity
            if frame != IDENTITY:
                raise self.fail(WOBJ_REFUSED, clip(f"{name} {frame_text(frame)}"))
        self.what = "grip load"
        gripload = self.load()
        self.what = "timestamp"
        stamp = self.string("timestamp")
        self.what = "seqno"
        seqno = self.num()
        self.what = "EGM"
        if self.num() != 0:
            raise self.fail("EGM not supported", "the file asks for an EGM configuration")
        return int(version), gripload, stamp, round(seqno)

    # --- tb_command ------------------------------------------------------------------------------
    def command(self, n: int) -> Command:
        """Command ``n`` (1-based), read and checked."""
        if n > MAX_COMMANDS:
            raise self.fail("Too many commands", f"more than {MAX_COMMANDS}")
        self.what = f"command {n}"
        cmd_num, op = self.num(), self.num()
        what = f"cmd_num {num_to_str(cmd_num, 0)}"
        k = round(cmd_num)
        if op == 1.0:
            self.what = f"MoveAbsJ {what} jointtarget"
            jt = JointTarget(self.nums(6), self.nums(6))
            return MoveAbsJ(k, jt, self.speed(f"MoveAbsJ {what}"), self.zone(f"MoveAbsJ {what}"))
        if op in (2.0, 3.0):
            kind = "MoveJ" if op == 2.0 else "MoveL"
            pt, speed, zone = self.target(f"{kind} {what}")
            return (MoveJ if op == 2.0 else MoveL)(k, pt, speed, zone)
        if op == 5.0:
            what = f"WaitTime {what}"
            self.what = what
            t = self.num()
            if t < 0:
                raise self.fail("Invalid WaitTime", f"{what}: {num_to_str(t, 2)} s")
            if t > WAIT_MAX:
                raise self.fail(WAIT_OVER, clip(f"{what}: {num_to_str(t, 2)} s > TB_WAIT_MAX "
                                                f"{num_to_str(WAIT_MAX, 2)}"))
            return WaitTime(k, t)
        unsupported = {4.0: "MoveC", 6.0: "CirPathMode", 7.0: "SyncMoveOn", 8.0: "SyncMoveOff"}
        if op in unsupported:
            raise self.fail("Unsupported command", f"{unsupported[op]} {what}")
        raise self.fail("Invalid motion program command",
                        f"unknown opcode {num_to_str(op, 0)} ({what})")

    def target(self, what: str) -> tuple[RobTarget, SpeedData, ZoneData]:
        """``tb_target``: the robtarget (not below ``tb_floor_z``), its speed and zone."""
        self.what = f"{what} robtarget"
        p = self.pose()
        pt = RobTarget(p.trans, p.rot, ConfData(*self.nums(4)), self.nums(6))
        floor = self.limits.floor_z
        if pt.trans[2] < floor:
            raise self.fail("Target below the table", f"{what}: z {num_to_str(pt.trans[2], 1)} "
                                                      f"mm < {num_to_str(floor, 1)} mm")
        return pt, self.speed(what), self.zone(what)

    def speed(self, what: str) -> SpeedData:
        """``tb_speeddata``: each speed above 0 and at most its cap."""
        self.what = f"{what} speeddata"
        s = SpeedData(*self.nums(4))
        lim = self.limits
        for field, v, name, cap in (("v_tcp", s.v_tcp, "tb_v_tcp_max", lim.v_tcp_max),
                                    ("v_ori", s.v_ori, "tb_v_ori_max", lim.v_ori_max),
                                    ("v_leax", s.v_leax, "TB_V_LEAX_MAX", V_LEAX_MAX),
                                    ("v_reax", s.v_reax, "tb_v_reax_max", lim.v_reax_max)):
            if v <= 0:
                raise self.fail("Invalid speed", f"{what}: {field} = {num_to_str(v, 2)}")
            self.over(SPEED_OVER, what, field, v, name, cap)
        return s

    def zone(self, what: str) -> ZoneData:
        """``tb_zonedata``: finep a bool, each other field from 0 to z10's."""
        self.what = f"{what} zonedata"
        finep = self.flag(f"{what} finep")
        z = ZoneData(finep, *self.nums(6))
        for field, (name, cap) in ZONE_MAX.items():
            v = float(getattr(z, field))
            if v < 0:
                raise self.fail("Invalid zone", f"{what}: {field} = {num_to_str(v, 2)}")
            self.over(ZONE_OVER, what, field, v, name, cap)
        return z

    def over(self, reason: str, what: str, field: str, v: float, name: str, cap: float) -> None:
        """``tb_over``: refused when ``v`` is above ``cap``."""
        if v > cap:
            raise self.fail(reason, clip(f"{what}: {field} {num_to_str(v, 2)} > {name} "
                                         f"{num_to_str(cap, 2)}"))


def read_program(data: bytes, held: ToolData, limits: Limits) -> MotionProgramFile:
    """``tb_run``'s reading of ``data`` (the task's file): the program as it will run (its
    tool ``held``, the controller's ``tool_pusher``; its work object wobj0), or the
    refusal (:class:`RapidError` 80001, our RAPID's lines but the file's, which
    :func:`sim_twin.rws.testbed_rapid.ours` fills in) at the first field that fails."""
    r = _TbReader(data, held, limits)
    try:
        version, gripload, stamp, seqno = r.header()
        commands: list[Command] = []
        while r.pos < len(r.data):
            commands.append(r.command(len(commands) + 1))
    except _Refused as exc:
        raise exc.error from None
    wobj0 = WobjData(False, True, "", IDENTITY, IDENTITY)
    return MotionProgramFile(version, held, wobj0, gripload, stamp, seqno, EgmConfig("none"),
                             tuple(commands))
