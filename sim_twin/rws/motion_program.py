"""The binary motion program file ``abb_motion_program_exec`` uploads, decoded as its
RAPID module reads it: typed commands with targets in mm and quaternions.

Why it exists: the library's client turns a ``MotionProgram`` into a file of little-endian
float32 values (``MotionProgram.get_program_bytes``), uploads it to the controller's RAM
disk and starts RAPID; its RAPID module reads the file and runs the commands. The twin's
start hook (``motion_exec``) must run the very same bytes, so this module reads them the
way that module must: field by field, refusing a file it cannot read with the error a
RAPID module writes (``ErrWrite``: event log 80001, header "Motion Program Failed"), which
the client turns into its exception.

The layout (learnt from the library's Python writer, version 10011; every value a float32,
booleans 0/1, a string a float32 length and 32 bytes padded with spaces):

    version 10011
    tooldata   robhold, tframe (pose: x y z, qw qx qy qz), tload (loaddata: mass, cog xyz,
               aom wxyz, ix iy iz)
    wobjdata   robhold, ufprog, ufmec (string), uframe (pose), oframe (pose)
    loaddata   the grip load
    string     the timestamp (YYYY-MM-DD-HH-MM-SS-ffff)
    num        the seqno
    egm        a kind (0 none/stream, 1 joint target, 2 pose target, 3 path correction) and
               that kind's numbers (0, 14, 30, 7)
    then, until the end of the file, per command: cmd_num, opcode, the command's fields.

Opcodes: 1 MoveAbsJ (jointtarget, speeddata, zonedata), 2 MoveJ and 3 MoveL (robtarget,
speeddata, zonedata), 4 MoveC (robtarget circle point, robtarget, speeddata, zonedata),
5 WaitTime (seconds), 6 CirPathMode (switch 1..6), 7 SyncMoveOn, 8 SyncMoveOff (no
fields), 50001 EGMRunJoint (cond, ramp in, ramp out), 50002 EGMRunPose (the same and an
offset pose), 50003 EGMMoveL, 50004 EGMMoveC (as MoveL, MoveC). A robtarget is 17 numbers
(pose, confdata cf1 cf4 cf6 cfx, 6 external axes), a jointtarget 12 (6 robot axes, 6
external), speeddata 4 (v_tcp mm/s, v_ori deg/s, v_leax, v_reax), zonedata 7 (finep as
0/1, then pzone_tcp, pzone_ori, pzone_eax, zone_ori, zone_leax, zone_reax).

Over 450 lines, on purpose: the file format: every command decoded in the order the
RAPID module reads it, one table of the format.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass

from sim_twin.rws.irc5 import RapidError

FILE_VERSION = 10011
ERRWRITE_ERROR, ERRWRITE_WARNING, ERRWRITE_INFO = 80001, 80002, 80003
"""The event log codes of RAPID's ``ErrWrite`` (error), ``ErrWrite \\W``, ``ErrWrite \\I``:
what a RAPID module writes itself (domain 8, "user")."""
FAILED = "Motion Program Failed"
"""The header the client looks for (``args[0]``) in an entry of type 2 or 3; it raises
with the four reason lines ``args[1:5]``."""
STRING_BYTES = 32
Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
_F32 = struct.Struct("<f")


class ProgramFileError(RapidError):
    """The file cannot be run: an ErrWrite entry (80001, "Motion Program Failed") whose
    reason lines are ``reason``, the file, ``detail`` and the byte offset."""

    def __init__(self, reason: str, detail: str, *, path: str = "", offset: int | None = None,
                 task: str | None = None) -> None:
        at = "" if offset is None else f"at byte {offset}"
        super().__init__(ERRWRITE_ERROR, FAILED, task=task,
                         desc=f"{reason}: {detail} {at}".strip(),
                         args=(FAILED, reason, path, detail, at))
        self.reason, self.detail, self.path, self.offset = reason, detail, path, offset


def program_failed(reason: str, detail: str, *, task: str | None = None, where: str = ""
                   ) -> RapidError:
    """The error a RAPID motion task reports when it cannot run a command (same shape)."""
    return RapidError(ERRWRITE_ERROR, FAILED, task=task, desc=f"{reason}: {detail}",
                      args=(FAILED, reason, where, detail, ""))


# --- the records --------------------------------------------------------------------------
@dataclass(frozen=True)
class Pose:
    trans: Vec3
    rot: Quat
    """[qw, qx, qy, qz]"""


@dataclass(frozen=True)
class LoadData:
    mass: float
    cog: Vec3
    aom: Quat
    ix: float
    iy: float
    iz: float


@dataclass(frozen=True)
class ToolData:
    robhold: bool
    tframe: Pose
    tload: LoadData


@dataclass(frozen=True)
class WobjData:
    robhold: bool
    ufprog: bool
    ufmec: str
    uframe: Pose
    oframe: Pose


@dataclass(frozen=True)
class ConfData:
    cf1: float
    cf4: float
    cf6: float
    cfx: float


@dataclass(frozen=True)
class RobTarget:
    trans: Vec3
    rot: Quat
    robconf: ConfData
    extax: tuple[float, ...]


@dataclass(frozen=True)
class JointTarget:
    robax: tuple[float, ...]
    """6 robot axes, degrees."""
    extax: tuple[float, ...]
    """6 external axes (on a YuMi the first is axis 7, the arm angle)."""


@dataclass(frozen=True)
class SpeedData:
    v_tcp: float
    v_ori: float
    v_leax: float
    v_reax: float


@dataclass(frozen=True)
class ZoneData:
    finep: bool
    pzone_tcp: float
    pzone_ori: float
    pzone_eax: float
    zone_ori: float
    zone_leax: float
    zone_reax: float


# --- the commands ------------------------------------------------------------------------
@dataclass(frozen=True)
class MoveAbsJ:
    cmd_num: int
    to_joint_pos: JointTarget
    speed: SpeedData
    zone: ZoneData


@dataclass(frozen=True)
class MoveJ:
    cmd_num: int
    to_point: RobTarget
    speed: SpeedData
    zone: ZoneData


@dataclass(frozen=True)
class MoveL:
    cmd_num: int
    to_point: RobTarget
    speed: SpeedData
    zone: ZoneData


@dataclass(frozen=True)
class MoveC:
    cmd_num: int
    cir_point: RobTarget
    to_point: RobTarget
    speed: SpeedData
    zone: ZoneData


@dataclass(frozen=True)
class WaitTime:
    cmd_num: int
    t: float


@dataclass(frozen=True)
class CirPathMode:
    cmd_num: int
    switch: int
    """1 PathFrame, 2 ObjectFrame, 3 CirPointOri, 4 Wrist45, 5 Wrist46, 6 Wrist56."""


@dataclass(frozen=True)
class SyncMoveOn:
    cmd_num: int


@dataclass(frozen=True)
class SyncMoveOff:
    cmd_num: int


@dataclass(frozen=True)
class EGMRunJoint:
    cmd_num: int
    cond_time: float
    ramp_in_time: float
    ramp_out_time: float


@dataclass(frozen=True)
class EGMRunPose:
    cmd_num: int
    cond_time: float
    ramp_in_time: float
    ramp_out_time: float
    offset: Pose


@dataclass(frozen=True)
class EGMMoveL:
    cmd_num: int
    to_point: RobTarget
    speed: SpeedData
    zone: ZoneData


@dataclass(frozen=True)
class EGMMoveC:
    cmd_num: int
    cir_point: RobTarget
    to_point: RobTarget
    speed: SpeedData
    zone: ZoneData


Command = (MoveAbsJ | MoveJ | MoveL | MoveC | WaitTime | CirPathMode | SyncMoveOn
           | SyncMoveOff | EGMRunJoint | EGMRunPose | EGMMoveL | EGMMoveC)
EGM_KINDS = {0: "none", 1: "joint_target", 2: "pose_target", 3: "path_correction"}
_EGM_COUNTS = {0: 0, 1: 14, 2: 30, 3: 7}


@dataclass(frozen=True)
class EgmConfig:
    """The EGM set-up of the program: ``kind`` (none also means stream-only: the writer
    encodes both as 0) and its numbers in file order."""

    kind: str
    values: tuple[float, ...] = ()


@dataclass(frozen=True)
class MotionProgramFile:
    version: int
    tool: ToolData
    wobj: WobjData
    gripload: LoadData
    timestamp: str
    seqno: int
    egm: EgmConfig
    commands: tuple[Command, ...]


# --- reading -------------------------------------------------------------------------------
class _Reader:
    """Float32 fields from the file, each failure a :class:`ProgramFileError`."""

    def __init__(self, data: bytes, path: str) -> None:
        self.data, self.path, self.pos = data, path, 0
        self.what = "the header"

    def fail(self, reason: str, detail: str, offset: int | None = None) -> ProgramFileError:
        return ProgramFileError(reason, detail, path=self.path,
                                offset=self.pos if offset is None else offset)

    @property
    def at_end(self) -> bool:
        return self.pos >= len(self.data)

    def num(self) -> float:
        if self.pos + 4 > len(self.data):
            raise self.fail("Motion program file truncated",
                            f"{self.what} ends after {len(self.data)} bytes")
        (v,) = _F32.unpack_from(self.data, self.pos)
        if not math.isfinite(v):
            raise self.fail("Invalid number in motion program", f"{self.what}: {v}")
        self.pos += 4
        return float(v)

    def nums(self, n: int) -> tuple[float, ...]:
        return tuple(self.num() for _ in range(n))

    def integer(self, what: str) -> int:
        start = self.pos
        v = self.num()
        if v != int(v):
            raise self.fail("Invalid number in motion program",
                            f"{what} must be a whole number, got {v:g}", start)
        return int(v)

    def flag(self, what: str) -> bool:
        start = self.pos
        v = self.num()
        if v not in (0.0, 1.0):
            raise self.fail("Invalid bool in motion program",
                            f"{self.what}: {what} must be 0 or 1, got {v:g}", start)
        return v == 1.0

    def string(self, what: str) -> str:
        start = self.pos
        n = self.integer(f"{what}'s length")
        if not 0 <= n <= STRING_BYTES:
            raise self.fail("Invalid string in motion program",
                            f"{what}: length {n} (0..{STRING_BYTES})", start)
        if self.pos + STRING_BYTES > len(self.data):
            raise self.fail("Motion program file truncated", f"{what} is cut off")
        raw = self.data[self.pos:self.pos + n]
        self.pos += STRING_BYTES
        try:
            return raw.decode("ascii")
        except UnicodeDecodeError:
            raise self.fail("Invalid string in motion program", f"{what} is not ASCII",
                            start) from None

    # records
    def pose(self) -> Pose:
        x, y, z, qw, qx, qy, qz = self.nums(7)
        return Pose((x, y, z), (qw, qx, qy, qz))

    def loaddata(self) -> LoadData:
        m, cx, cy, cz, aw, ax, ay, az, ix, iy, iz = self.nums(11)
        return LoadData(m, (cx, cy, cz), (aw, ax, ay, az), ix, iy, iz)

    def tooldata(self) -> ToolData:
        return ToolData(self.flag("robhold"), self.pose(), self.loaddata())

    def wobjdata(self) -> WobjData:
        robhold, ufprog = self.flag("robhold"), self.flag("ufprog")
        return WobjData(robhold, ufprog, self.string("ufmec"), self.pose(), self.pose())

    def robtarget(self) -> RobTarget:
        p = self.pose()
        return RobTarget(p.trans, p.rot, ConfData(*self.nums(4)), self.nums(6))

    def jointtarget(self) -> JointTarget:
        return JointTarget(self.nums(6), self.nums(6))

    def speeddata(self) -> SpeedData:
        return SpeedData(*self.nums(4))

    def zonedata(self) -> ZoneData:
        return ZoneData(self.flag("finep"), *self.nums(6))


def _move(cls: type[MoveJ | MoveL | EGMMoveL]) -> Callable[[_Reader, int], Command]:
    return lambda r, n: cls(n, r.robtarget(), r.speeddata(), r.zonedata())


def _circle(cls: type[MoveC | EGMMoveC]) -> Callable[[_Reader, int], Command]:
    return lambda r, n: cls(n, r.robtarget(), r.robtarget(), r.speeddata(), r.zonedata())


def _cir_path_mode(r: _Reader, n: int) -> CirPathMode:
    start = r.pos
    switch = r.integer("the CirPathMode switch")
    if not 1 <= switch <= 6:
        raise r.fail("Invalid CirPathMode switch", f"{switch} (1..6)", start)
    return CirPathMode(n, switch)


_DECODERS: dict[int, tuple[str, Callable[[_Reader, int], Command]]] = {
    1: ("MoveAbsJ", lambda r, n: MoveAbsJ(n, r.jointtarget(), r.speeddata(), r.zonedata())),
    2: ("MoveJ", _move(MoveJ)),
    3: ("MoveL", _move(MoveL)),
    4: ("MoveC", _circle(MoveC)),
    5: ("WaitTime", lambda r, n: WaitTime(n, r.num())),
    6: ("CirPathMode", _cir_path_mode),
    7: ("SyncMoveOn", lambda r, n: SyncMoveOn(n)),
    8: ("SyncMoveOff", lambda r, n: SyncMoveOff(n)),
    50001: ("EGMRunJoint", lambda r, n: EGMRunJoint(n, *r.nums(3))),
    50002: ("EGMRunPose", lambda r, n: EGMRunPose(n, *r.nums(3), r.pose())),
    50003: ("EGMMoveL", _move(EGMMoveL)),
    50004: ("EGMMoveC", _circle(EGMMoveC)),
}
OPCODES = {name: op for op, (name, _) in _DECODERS.items()}


def _header(r: _Reader) -> tuple[ToolData, WobjData, LoadData, str, int, EgmConfig]:
    r.what = "the tooldata"
    tool = r.tooldata()
    r.what = "the wobjdata"
    wobj = r.wobjdata()
    r.what = "the grip load"
    gripload = r.loaddata()
    r.what = "the timestamp"
    timestamp = r.string("the timestamp")
    r.what = "the seqno"
    seqno = r.integer("the seqno")
    r.what = "the EGM configuration"
    start = r.pos
    kind = r.integer("the EGM kind")
    if kind not in _EGM_COUNTS:
        raise r.fail("Invalid EGM configuration", f"kind {kind} (0..3)", start)
    egm = EgmConfig(EGM_KINDS[kind], r.nums(_EGM_COUNTS[kind]))
    return tool, wobj, gripload, timestamp, seqno, egm


def decode_program(data: bytes, path: str = "") -> MotionProgramFile:
    """The program in ``data`` (``path`` names it in errors); :class:`ProgramFileError`
    if the file is not a version-10011 program, is cut off, or holds an unknown command."""
    r = _Reader(bytes(data), path)
    if not data:
        raise r.fail("Motion program file empty", "no bytes")
    version = r.num()
    if version != FILE_VERSION:
        raise r.fail("Invalid motion program file version",
                     f"{version:g} (this controller reads {FILE_VERSION})", 0)
    tool, wobj, gripload, timestamp, seqno, egm = _header(r)
    commands: list[Command] = []
    while not r.at_end:
        start = r.pos
        r.what = f"command {len(commands) + 1}"
        cmd_num = r.integer(f"{r.what}'s cmd_num")
        opcode = r.integer(f"{r.what}'s opcode")
        entry = _DECODERS.get(opcode)
        if entry is None:
            raise r.fail("Invalid motion program command",
                         f"unknown opcode {opcode} (cmd_num {cmd_num})", start)
        r.what = f"command {len(commands) + 1} ({entry[0]}, cmd_num {cmd_num})"
        commands.append(entry[1](r, cmd_num))
    return MotionProgramFile(int(version), tool, wobj, gripload, timestamp, seqno, egm,
                             tuple(commands))


# --- where a task's program is ---------------------------------------------------------------
_TRAILING_DIGITS = re.compile(r"^.*[A-Za-z_](\d+)$")


def program_file_for_task(task: str) -> str:
    """The RAM-disk file a motion task reads: ``motion_program.bin`` for ``T_ROB1`` and for
    a task whose name does not end in digits (``T_ROB_L``, ``T_ROB_R``!), else
    ``motion_program<n>.bin`` for a name ending in ``<n>`` (``T_ROB2`` -> 2).

    This is the rule the library's client names its uploads by; the twin assumes the
    library's RAPID module opens its file by the same rule (it must, for the client's
    own ``T_ROB1``/``T_ROB2`` MultiMove to work). So on a YuMi both arms' tasks read ONE
    file: see docs/notes/rws.md, "Motion programs on the twin"."""
    m = _TRAILING_DIGITS.match(task)
    suffix = "" if task == "T_ROB1" or m is None else str(int(m.group(1)))
    return f"RAMDISK:motion_program{suffix}.bin"


def describe(cmd: Command) -> str:
    """``MoveL 3``: the command's RAPID name and cmd_num (for errors)."""
    return f"{type(cmd).__name__} {cmd.cmd_num}"
