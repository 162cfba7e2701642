"""The RWS twin's start hook for OUR RAPID (``robot/rapid/``), not the library's.

Why it exists: ``abb_motion_program_exec`` names a task's program file after the task's
trailing digits, so on a YuMi (``T_ROB_L``, ``T_ROB_R``) both arms' programs land in one
file (see :mod:`sim_twin.rws.motion_exec`, which plays that library behaviour on
purpose). The project therefore ships its own RAPID modules that read the same binary
format from a file FIXED PER TASK, and the driver uploads to those names. For the agent's
controller client to run that path before the robot, the twin must do what those modules
do; this hook does, on the same cell machinery as :class:`CellMotion`.

What our RAPID does, and so this hook (docs/notes/rws.md, "Our RAPID side"):

1. Each started motion task reads ITS file, ``RAMDISK:testbed_<task>.bin``
   (:func:`testbed_program_file`), in full before its first motion, and refuses it
   (an ``ErrWrite`` error entry, 80001, header ``Testbed Motion Failed``, reason lines:
   the reason, the file, the detail, the byte offset) when it cannot be read, has another
   version, asks for EGM, holds a command other than MoveAbsJ, MoveJ, MoveL and WaitTime,
   holds more than :data:`MAX_COMMANDS`, or a robtarget below the table
   (``floor_z_mm``, the program's work object frame). A refused task does not move and
   does not stop the other task (independent MultiMove tasks: an ``ErrWrite`` is a log
   entry, not a stop); the twin's own limits (a joint target other than the rest, an
   orientation other than tool-down) are refused the same way.
2. The tasks that accepted their program move together (MultiMove, not path
   synchronised). A motion the cell refuses mid-run is a RAPID error that stops the run
   (as a motion error stops a controller), with the same header.
3. After its last command (``WaitRob \\InPos``: the arm has arrived), each task writes
   ``ErrWrite \\I`` (80003) ``Testbed Motion Done``, reason lines: the task, ``seqno <n>``
   (the program header's), ``commands <k>``, the file. No log file, no signals.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from sim_twin.rws.event_log import MSG_ERROR, MSG_INFO
from sim_twin.rws.irc5 import ProgramRun, RapidError
from sim_twin.rws.mechunits import MechUnit
from sim_twin.rws.motion_exec import CellMotion, TaskProgram
from sim_twin.rws.motion_program import (
    ERRWRITE_ERROR,
    ERRWRITE_INFO,
    MotionProgramFile,
    MoveAbsJ,
    MoveJ,
    MoveL,
    WaitTime,
    describe,
)

DONE, FAILED = "Testbed Motion Done", "Testbed Motion Failed"
"""The headers (``args[0]``) of our RAPID's event log entries; the driver reads them."""
MAX_COMMANDS = 64
"""The size of our RAPID's command arrays (``TB_MAX_CMDS`` in TestbedMotion.mod)."""
SUPPORTED = (MoveAbsJ, MoveJ, MoveL, WaitTime)


def testbed_program_file(task: str) -> str:
    """The file our RAPID's task ``task`` reads (``RAMDISK:`` + ``tb_name`` in its task module)."""
    return f"RAMDISK:testbed_{task}.bin"


def _refusal(reason: str, detail: str) -> RapidError:
    return RapidError(ERRWRITE_ERROR, FAILED, desc=f"{reason}: {detail}",
                      args=(FAILED, reason, "", detail, ""))


def check_program(program: MotionProgramFile, floor_z_mm: float) -> None:
    """What our RAPID checks of a decoded program before its first motion."""
    if program.egm.kind != "none":
        raise _refusal("EGM not supported", f"EGM configuration {program.egm.kind}")
    if len(program.commands) > MAX_COMMANDS:
        raise _refusal("Too many commands",
                       f"{len(program.commands)} > {MAX_COMMANDS}")
    for cmd in program.commands:
        if not isinstance(cmd, SUPPORTED):
            raise _refusal("Unsupported command", describe(cmd))
        if isinstance(cmd, MoveJ | MoveL) and cmd.to_point.trans[2] < floor_z_mm:
            raise _refusal("Target below the table",
                           f"{describe(cmd)}: z {cmd.to_point.trans[2]:g} mm < "
                           f"{floor_z_mm:g} mm")


def ours(exc: RapidError, path: str, task: str) -> RapidError:
    """``exc`` (the decoder's or the cell's refusal) as our RAPID's entry."""
    args: Sequence[Any] = exc.args if len(exc.args) == 5 else (FAILED, exc.title, "", "", "")
    return RapidError(ERRWRITE_ERROR, FAILED, task=task, desc=exc.desc,
                      args=(FAILED, args[1], path, args[3], args[4]))


class TestbedRapid(CellMotion):
    """The start hook of our RAPID: ``Irc5Controller(units=units, poses=hook.poses,
    on_start=hook)``. As :class:`CellMotion` (``cell``, ``cell_lock``, ``units``,
    ``pusher_length_mm``, ``frame_every_s``), plus ``files`` (task -> the file it reads;
    default :func:`testbed_program_file`) and ``floor_z_mm`` (our RAPID's ``tb_floor_z``).
    ``last_run``: what each task of the latest run read (accepted or not)."""

    __test__ = False  # not a pytest class, whatever its name

    def __init__(self, *args: Any, files: Mapping[str, str] | None = None,
                 floor_z_mm: float = 0.0, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.files = {t.upper(): f for t, f in (files or {}).items()}
        self.floor_z_mm = float(floor_z_mm)

    def program_file(self, task: str) -> str:
        return self.files.get(task.upper(), testbed_program_file(task))

    def _read(self, run: ProgramRun, unit: MechUnit) -> TaskProgram:
        tp = self.read_task(run, unit)
        self.last_run[unit.task] = tp
        check_program(tp.program, self.floor_z_mm)
        return tp

    def _failed(self, run: ProgramRun, unit: MechUnit, exc: RapidError) -> None:
        e = ours(exc, self.program_file(unit.task), unit.task)
        run.controller.elog.write(e.code, MSG_ERROR, e.title, desc=e.desc, args=e.args,
                                  src_name=unit.task)

    def __call__(self, run: ProgramRun) -> None:
        self.last_run = {}
        started = {t.upper() for t in run.tasks}
        plans, accepted = {}, []
        for unit in (u for u in self.units if u.task.upper() in started):
            try:
                tp = self._read(run, unit)
                plans.update(self._plans(run, [tp]))
            except RapidError as exc:
                self._failed(run, unit, exc)
                continue
            accepted.append(tp)
        if not accepted:
            return
        try:
            done = self._rounds(run, plans, None, accepted[0].unit.arm)
        except RapidError as exc:
            task = exc.task or accepted[0].task
            raise ours(exc, self.program_file(task), task) from None
        if not done:
            return  # stopped: no "Done" entry
        for tp in accepted:
            run.controller.elog.write(
                ERRWRITE_INFO, MSG_INFO, DONE, src_name=tp.task,
                args=(DONE, tp.task, f"seqno {tp.program.seqno}",
                      f"commands {len(tp.program.commands)}", tp.path))
