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
   holds more than :data:`MAX_COMMANDS`, a robtarget below the table (``tb_floor_z``),
   or any field past the limits the controller holds (issue 43: a speed above the task
   module's caps, a zone above z10's, a wait above ``TB_WAIT_MAX``, a work object other
   than wobj0's, a number that is not finite): read field by field as the module reads
   it, the first failing field named (:mod:`sim_twin.rws.testbed_file`, which the
   property test tests/sim_twin/test_rws_hostile_files.py holds to the module's
   order). An accepted file runs in wobj0, after ``VelSet 100, tb_v_tcp_max``
   (:meth:`TestbedRapid.velset`). A refused task does not move and
   does not stop the other task (independent MultiMove tasks: an ``ErrWrite`` is a log
   entry, not a stop); a motion the arm cannot make (a joint limit, out of reach) is the
   controller's own code when the move is run.
2. The tasks that accepted their program move together (MultiMove, not path
   synchronised). A motion the cell refuses mid-run is a RAPID error that stops the run
   (as a motion error stops a controller), with the same header.
3. After its last command (``WaitRob \\InPos``: the arm has arrived), each task writes
   ``ErrWrite \\I`` (80003) ``Testbed Motion Done``, reason lines: the task, ``seqno <n>``
   (the program header's), ``commands <k>``, the file. No log file, no signals.
4. The controller supervises the stationary world zones ``tb_zones`` defined at power on
   (:mod:`sim_twin.rws.world_zones`): when a task's TCP of ``tool_pusher`` (the
   program's tool) would enter one, EVERY arm stops at that moment (the offending pusher
   on the zone's face), the controller's own error (:data:`WORLD_ZONE_CODE`) goes to the
   event log in that task, and execution stops: no ``Done`` entry.
5. The tool is the CONTROLLER's (issue 35): ``tool_pusher``, the TASK PERS of the task
   module (``TestbedTask_L`` / ``_R``; readable and writable over RWS), never the file's.
   ``tb_header`` compares the file's ``tframe`` with ``tool_pusher.tframe`` and refuses
   the file, before any motion, when they are more than :data:`TOOL_MM` apart in
   translation or :data:`TOOL_DEG` in rotation
   (:func:`~sim_twin.rws.testbed_file.tool_differs`: reason :data:`TOOL_DIFFERS`, the
   detail line the file's frame, the last line
   ``tool_pusher``'s). An accepted program moves, and is supervised, with
   ``tool_pusher`` (:meth:`TestbedRapid.held_tool`): the motion executor gets the
   program with the controller's tool in place of the file's, so the TCP it moves and
   the zones watch is the controller's frame.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping, Sequence
from typing import Any

from sim_twin.rws.errors import RwsError
from sim_twin.rws.event_log import MSG_ERROR, MSG_INFO
from sim_twin.rws.irc5 import ProgramRun, RapidError
from sim_twin.rws.mechunits import MechUnit
from sim_twin.rws.motion_exec import (
    CellMotion,
    ControllerStop,
    TaskProgram,
    ZoneStop,
    tool_offset,
)
from sim_twin.rws.motion_program import (
    ERRWRITE_ERROR,
    ERRWRITE_INFO,
    LoadData,
    Pose,
    ProgramFileError,
    ToolData,
    decode_program,
)
from sim_twin.rws.rapid_data import numbers, parse_value
from sim_twin.rws.testbed_file import (  # re-exported: the twin's names of our RAPID's
    DONE,
    FAILED,
    MAX_COMMANDS,
    TOOL_DEG,
    TOOL_DIFFERS,
    TOOL_MM,
    V_ORI_MAX,
    V_REAX_MAX,
    V_TCP_MAX,
    Limits,
    angle_deg,
    frame_text,
    read_program,
    refusal,
)
from sim_twin.rws.world_zones import ArmZone, default_zone

__all__ = ["CAPS", "DONE", "FAILED", "MAX_COMMANDS", "RAPID_VERSION", "TOOL_DEG", "TOOL_DIFFERS",
           "TOOL_MM", "WORLD_ZONE_CODE", "WORLD_ZONE_TITLE", "TestbedRapid", "WorldZoneStop",
           "angle_deg", "frame_text", "ours", "task_module_of", "testbed_program_file",
           "tool_of"]
"""The twin's names of our RAPID (those of :mod:`sim_twin.rws.testbed_file` included)."""

RAPID_VERSION = 5
"""``TB_RAPID_VERSION`` in TestbedMotion.mod: the behaviour of our modules this twin plays
(2: the world zones; 3: the zones in a system module, issue 29; 4: the tool frame is the
controller's and a file's must match it, tb_zones writes "Testbed Zones Active", issue
35; 5: every field a file can set has a limit the controller holds, VelSet, the moves in
wobj0, issue 43). The driver and ``testbed check`` compare the controller's."""
CAPS = ("tb_v_tcp_max", "tb_v_ori_max", "tb_v_reax_max")
"""The speed caps each task module declares (CONST num), read at every start."""

WORLD_ZONE_CODE = 50000
WORLD_ZONE_TITLE = "World zone reached"
"""The twin's OWN code and title for a ``WZLimSup`` stop (motion domain, 5xxxx, like the
controller's motion errors): RobotWare's real event for it was not found in any manual
at hand (the operating manual's event list was not in the search corpus), so this is a
placeholder the driver must not depend on; docs/rws-checklist.md asks for the real one.
The driver reports any error entry (type 3) as the step's failure, whatever its code."""


def testbed_program_file(task: str) -> str:
    """The file our RAPID's task ``task`` reads and names in its entries (``tb_path``:
    ``RAMDISK:/`` + ``tb_name`` of its task module)."""
    return f"RAMDISK:/testbed_{task}.bin"


def tool_of(value: str) -> ToolData:
    """A ``tooldata`` symbol's RAPID text as the decoder's record."""
    v = parse_value(value)
    if not isinstance(v, list) or len(v) != 3 or not isinstance(v[0], bool):
        raise ValueError(f"not a tooldata: {value!r}")
    f, load = numbers(v[1]), numbers(v[2])
    return ToolData(v[0], Pose(tuple(f[:3]), tuple(f[3:7])),  # type: ignore[arg-type]
                    LoadData(load[0], tuple(load[1:4]), tuple(load[4:8]),  # type: ignore[arg-type]
                             load[8], load[9], load[10]))


def ours(exc: RapidError, path: str, task: str) -> RapidError:
    """``exc`` (the decoder's or the cell's refusal) as our RAPID's entry."""
    args: Sequence[Any] = exc.args if len(exc.args) == 5 else (FAILED, exc.title, "", "", "")
    return RapidError(ERRWRITE_ERROR, FAILED, task=task, desc=exc.desc,
                      args=(FAILED, args[1], path, args[3], args[4]))


class WorldZoneStop(RapidError):
    """The controller stopped every motion: a TCP reached a stationary world zone."""


class TestbedRapid(CellMotion):
    """The start hook of our RAPID: ``Irc5Controller(units=units, poses=hook.poses,
    on_start=hook)``. As :class:`CellMotion` (``cell``, ``cell_lock``, ``units``,
    ``pusher_length_mm``, ``frame_every_s``, ``on_frame``...), plus ``files`` (task ->
    the file it reads; default :func:`testbed_program_file`), ``floor_z_mm`` (our RAPID's
    ``tb_floor_z``) and ``zones`` (arm -> :class:`ArmZone`, the task module's zone
    constants; default: the arm's workspace grown by
    :data:`~sim_twin.rws.world_zones.DEFAULT_MARGIN_MM`, ``tb_zone_z`` 80 mm, the floor).
    ``caps`` (:data:`CAPS` -> value): the task modules' speed caps, default as shipped.
    ``last_run``: what each task of the latest run read (accepted or not; an accepted
    one with ``tool_pusher`` as its tool, as it ran). The modules'
    symbols (``tool_pusher``, the zone constants, ``TB_RAPID_VERSION``...) are declared by
    ``sim_twin.rws.testbed_install.TestbedInstall(controller, hook)``, which also sets
    ``on_start``; without it RWS reads of them answer as if the modules were missing."""

    __test__ = False  # not a pytest class, whatever its name
    conf_j = False
    sing_area_wrist = True
    """And SingArea \\Wrist: the pusher is round, its turn about its own axis is free."""
    """Our RAPID moves with ConfJ off (robot/rapid/TestbedMotion.mod): a MoveJ takes the
    configuration closest to the arm's, as the controller does (sim_twin/rws/arm_supervision.py)."""

    def __init__(self, *args: Any, files: Mapping[str, str] | None = None,
                 floor_z_mm: float = 0.0, zones: Mapping[str, ArmZone] | None = None,
                 caps: Mapping[str, float] | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.files = {t.upper(): f for t, f in (files or {}).items()}
        self.floor_z_mm = float(floor_z_mm)
        self.zones = {u.arm: default_zone(self.cell.sides[u.arm], floor_z=self.floor_z_mm)
                      for u in self.units}
        self.zones.update(zones or {})
        self.caps = {**dict(zip(CAPS, (V_TCP_MAX, V_ORI_MAX, V_REAX_MAX), strict=True)),
                     **(caps or {})}
        """The speed caps the task modules declare (:data:`CAPS` -> value; default as
        shipped): what the lab set on this controller."""
        self._offsets: dict[str, tuple[float, float, float]] = {}
        self._velset: dict[str, float] = {}

    def program_file(self, task: str) -> str:
        return self.files.get(task.upper(), testbed_program_file(task))

    def held_tool(self, run: ProgramRun, task: str) -> ToolData | None:
        """``tool_pusher`` of ``task`` as the controller holds it now (None: the task
        module is not loaded)."""
        try:
            sym = run.controller.symbols.find([task, task_module_of(task), "tool_pusher"])
        except RwsError:
            return None
        return tool_of(sym.value)

    def limits(self, run: ProgramRun, task: str) -> Limits | None:
        """``tb_floor_z`` and the speed caps (:data:`CAPS`) of ``task``'s module as the
        controller holds them now (None: the module is not loaded)."""
        module, sym = task_module_of(task), run.controller.symbols
        try:
            got = {n: float(sym.find([task, module, n]).value) for n in ("tb_floor_z", *CAPS)}
        except (RwsError, ValueError):
            return None
        return Limits(got["tb_floor_z"], got["tb_v_tcp_max"], got["tb_v_ori_max"],
                      got["tb_v_reax_max"])

    def velset(self, task: str) -> float:
        """``VelSet 100, tb_v_tcp_max``: the TCP speed no move of ``task`` exceeds (the
        cap read at its latest start)."""
        return self._velset.get(task.upper(), super().velset(task))

    def _read(self, run: ProgramRun, unit: MechUnit) -> TaskProgram:
        """The task's file, read and checked as ``tb_run`` reads it
        (:func:`~sim_twin.rws.testbed_file.read_program`: every limit, the first failing
        field refused), to run with the controller's ``tool_pusher`` in wobj0
        (``last_run`` keeps the file as the library's decoder reads it until it is
        accepted, then the program as it runs)."""
        path = self.program_file(unit.task)
        try:
            data = run.controller.files.read(path)
        except RwsError:
            raise refusal("Motion program file not found", "nothing uploaded",
                          "at byte 0") from None
        with contextlib.suppress(ProgramFileError):
            self.last_run[unit.task] = TaskProgram(unit.task, unit, path,
                                                   decode_program(data, path))
        held, limits = self.held_tool(run, unit.task), self.limits(run, unit.task)
        if held is None or limits is None:
            raise refusal("Reference error", f"{task_module_of(unit.task)} is not loaded")
        tp = TaskProgram(unit.task, unit, path, read_program(data, held, limits))
        self.last_run[unit.task] = tp
        self._velset[unit.task.upper()] = limits.v_tcp_max
        return tp

    def _failed(self, run: ProgramRun, unit: MechUnit, exc: RapidError) -> None:
        e = ours(exc, self.program_file(unit.task), unit.task)
        run.controller.elog.write(e.code, MSG_ERROR, e.title, desc=e.desc, args=e.args,
                                  src_name=unit.task)

    def _run(self, run: ProgramRun) -> None:
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
        self._offsets = {tp.unit.arm: tool_offset(tp.program.tool, self.pusher_length_mm)
                         for tp in accepted}
        try:
            done = self._rounds(run, plans, None, accepted[0].unit.arm)
        except (WorldZoneStop, ControllerStop):
            raise  # the controller's own error, not our RAPID's
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

    # --- the world zones --------------------------------------------------------------------
    def _zone_error(self, zone: ZoneStop, tcps: Mapping[str, Sequence[float]]) -> RapidError:
        """The controller's error for a world-zone stop (``CellMotion._path_zone_stop``:
        along the path the arm's joints take): where the TCP of the tool in use stopped,
        on the zone's face (``zone.point``; without one, the cell's TCP plus the tool's
        offset)."""
        unit = next(u for u in self.units if u.arm == zone.arm)
        if zone.point is not None:
            p = [round(float(v), 1) + 0.0 for v in zone.point]
        else:
            off = self._offsets.get(zone.arm, (0.0, 0.0, 0.0))
            p = [round(tcps[zone.arm][k] + off[k], 1) + 0.0 for k in range(3)]
        where = f"[{p[0]:g},{p[1]:g},{p[2]:g}]"
        return WorldZoneStop(
            WORLD_ZONE_CODE, WORLD_ZONE_TITLE, task=unit.task,
            desc=f"Task {unit.task}: the TCP of tool_pusher reached the stationary world "
                 f"zone {zone.box.name} ({zone.box.rapid()}, world, mm) at {where}. "
                 "Every motion task stopped there.",
            causes="A programmed path leaves the zone box (tb_zone_lo, tb_zone_hi) below "
                   "tb_zone_z, or goes below tb_floor_z.",
            actions="Move the arm out of the zone (above tb_zone_z) and check the "
                    "targets against the calibration's table box.",
            args=(unit.task, zone.box.name, *(f"{v:g}" for v in p)))



def task_module_of(task: str) -> str:
    """Our task module of a motion task: ``T_ROB_L`` -> ``TestbedTask_L``."""
    return f"TestbedTask_{task.rsplit('_', 1)[-1]}"
