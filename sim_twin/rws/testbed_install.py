"""Our RAPID (``robot/rapid/``) as installed on the twin: the symbols its modules declare,
readable over RWS, and the start hook that plays them; loadable and unloadable.

Why it exists: the agent's preflight (``testbed check``) and the driver decide whether a
controller runs OUR modules, and which version with which zones, by reading module
symbols over RWS (``get_rapid_variable("tb_zone_lo", "T_ROB_L/TestbedTask_L")``); a
rehearsal must be able to show them a controller where the modules are missing or old.
So the twin declares, per motion task, what the modules declare at module scope, with
the values this twin was started with, and the lab side channel (``POST
/lab/controller {"rapid": "none"}``, ``{"rapid_version": 1}``) changes them.

Per task (``T_ROB_L`` -> module ``TestbedTask_L``, ``T_ROB_R`` -> ``TestbedTask_R``):

- ``TestbedTask_X`` (a SYSTEM module): ``tb_name`` (CONST string), ``tool_pusher`` (TASK
  PERS tooldata, the CONTROLLER's tool frame and load: ``tframe`` z = the twin pusher's
  true length, ``hook.pusher_length_mm``, as the lab's 4-point measurement would find
  it; a lab changes it over RWS, ``action=set``, and no program file does),
  ``tb_floor_z``, ``tb_zone_z`` (CONST num), ``tb_zone_lo`` = ``[x0,y0,0]``,
  ``tb_zone_hi`` = ``[x1,y1,0]`` (CONST pos), the speed caps ``tb_v_tcp_max``,
  ``tb_v_ori_max``, ``tb_v_reax_max`` (CONST num, ``hook.caps``: as shipped unless the twin
  was started with a lab's own; the hook reads them at every start);
- ``TestbedZones`` (a SYSTEM module): ``TB_WZ_FAR``, ``TB_WZ_COUNT`` (CONST num), the five
  TASK PERS ``wzstationary`` ``tb_wz_floor`` ... ``tb_wz_yhi`` (the identity ``WZLimSup``
  gave each zone), ``tb_zones_n`` (how many zones ``tb_zones`` activated at the last
  power on) and ``tb_zones_at`` (when), ``TB_ZONES_ACTIVE`` (CONST string), and the
  routine ``tb_zones``, the POWER_ON event routine of each task
  (:attr:`Irc5Controller.event_routines`), which ends with the info entry
  ``Testbed Zones Active`` (80003; the task, ``zones <n>``, the time);
- ``TestbedMotion`` (the PROGRAM module): ``TB_RAPID_VERSION``, ``TB_VERSION``,
  ``TB_MAX_CMDS``, ``TB_TOOL_MM``, ``TB_TOOL_DEG``, the limits ``TB_V_LEAX_MAX``,
  ``TB_WAIT_MAX``, ``TB_ZONE_MAX``, ``TB_PZONE_ORI_MAX``... (CONST num), ``TB_DIR``,
  ``TB_DONE``, ``TB_FAILED``, ``TB_TOOL_DIFFERS`` and the limits' reasons
  ``TB_SPEED_OVER``... (CONST string).

The world zones the hook supervises (``hook.zones``) are those ``tb_zones`` activated
since the last restart: a restart erases them (as the motion system does) and the
POWER_ON event routine defines them again, if a loaded module still holds it. "Reset
RAPID" (``pstart``) removes ``TestbedMotion`` (a start then runs nothing) and keeps the
system modules, so the zones come back; the issue-29 modules, with everything in program
modules, would lose them, and the twin shows it (tests/sim_twin/test_rws_zones.py).
Every restart keeps the TASK PERS (``tool_pusher``, ``tb_zones_n``, ``tb_zones_at`` read
what they held until ``tb_zones`` runs again); only the ``Testbed Zones Active`` entry,
newer than the restart's 10045, shows that it did. :meth:`TestbedInstall.set_event_routines`
(lab: ``{"event_routines": false}``) removes the POWER_ON configuration as a lab could,
so a restart defines no zones and writes no entry while ``tb_zones_n`` still reads 5.

Not loaded: none of these symbols, and a start runs nothing (no ``Done`` entry), as on a
controller whose tasks hold other programs.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

from sim_twin.rws.event_log import MSG_INFO
from sim_twin.rws.irc5 import RESTARTED, EventRoutine, Irc5Controller, RapidError
from sim_twin.rws.motion_program import ERRWRITE_INFO, FILE_VERSION
from sim_twin.rws.rapid_data import format_number
from sim_twin.rws.testbed_file import (
    NOT_FINITE,
    SPEED_OVER,
    V_LEAX_MAX,
    WAIT_MAX,
    WAIT_OVER,
    WOBJ_REFUSED,
    ZONE_MAX,
    ZONE_OVER,
)
from sim_twin.rws.testbed_rapid import (
    CAPS,
    DONE,
    FAILED,
    MAX_COMMANDS,
    RAPID_VERSION,
    TOOL_DEG,
    TOOL_DIFFERS,
    TOOL_MM,
    TestbedRapid,
    task_module_of,
)
from sim_twin.rws.world_zones import FAR, ArmZone

SHARED_MODULE = "TestbedMotion"
ZONES_MODULE = "TestbedZones"
ZONES_ROUTINE = "tb_zones"
ZONES_ACTIVE = "Testbed Zones Active"
"""``TB_ZONES_ACTIVE``: the header of the info entry (80003) ``tb_zones`` writes when all
its zones are active; ``args``: the header, the task, ``zones <n>``, the time."""
PUSHER_LOAD = "[0.272,[7.5,11.5,53.8],[1,0,0,0],0.0003,0.00032,0.00009]"
"""``tool_pusher``'s load in the task modules: the SmartGripper and the pusher (robot/README.md,
"The tool load")."""
Decl = tuple[str, str, str, str, str]
"""(module, name, type, value, storage)"""
LIMIT_REASONS = {"TB_SPEED_OVER": SPEED_OVER, "TB_WAIT_OVER": WAIT_OVER,
                 "TB_ZONE_OVER": ZONE_OVER, "TB_WOBJ_REFUSED": WOBJ_REFUSED,
                 "TB_NOT_FINITE": NOT_FINITE}
"""TestbedMotion's CONST strings of the issue-43 refusals' reasons."""


task_module = task_module_of
"""Our task module of a motion task: ``T_ROB_L`` -> ``TestbedTask_L``."""


def _num(v: float) -> str:
    return format_number(float(v))


class TestbedInstall:
    """Our modules in ``controller``'s tasks, played by ``hook``. ``loaded`` False: as if
    they were never loaded; ``version``: the ``TB_RAPID_VERSION`` the controller reports
    (an older one changes nothing else: the twin plays only this version)."""

    __test__ = False  # not a pytest class

    def __init__(self, controller: Irc5Controller, hook: TestbedRapid, *, loaded: bool = True,
                 version: int = RAPID_VERSION) -> None:
        self.controller, self.hook = controller, hook
        self.loaded, self.version = False, int(version)
        self.consts: dict[str, ArmZone] = dict(hook.zones)
        """Each arm's zone constants (what ``TestbedTask_X`` declares)."""
        hook.zones = {}  # none active until tb_zones has run
        controller.on_restart.append(self._restarted)
        self.set_event_routines(True)  # the lab's install step: the POWER_ON event routine
        controller.on_start = None
        if loaded:
            self.set_loaded(True)
            # the restart after the install: its entry first, as every restart writes it
            # (the driver needs a restart entry, then Zones Active: drivers/yumi/zones_proof.py)
            controller.elog.write(RESTARTED[0], MSG_INFO, RESTARTED[1], src_name="SYS",
                                  desc="The system has been restarted (Restart).",
                                  args=("Restart",))
            controller.run_event_routines("POWER_ON")

    def declarations(self) -> Iterator[tuple[str, Decl]]:
        """(task, declaration) of every symbol our modules put in the tasks."""
        for unit in self.hook.units:
            z = self.consts[unit.arm]
            mod = task_module(unit.task)
            name = self.hook.program_file(unit.task).split(":", 1)[-1].lstrip("/")
            pusher = (f"[TRUE,[[0,0,{_num(self.hook.pusher_length_mm)}],[1,0,0,0]],"
                      f"{PUSHER_LOAD}]")
            yield from ((unit.task, d) for d in (
                (mod, "tb_name", "string", f'"{name}"', "CONST"),
                (mod, "tool_pusher", "tooldata", pusher, "TASK PERS"),
                (mod, "tb_floor_z", "num", _num(z.floor_z), "CONST"),
                (mod, "tb_zone_z", "num", _num(z.zone_z), "CONST"),
                (mod, "tb_zone_lo", "pos", f"[{_num(z.x0)},{_num(z.y0)},0]", "CONST"),
                (mod, "tb_zone_hi", "pos", f"[{_num(z.x1)},{_num(z.y1)},0]", "CONST"),
                *((mod, cap, "num", _num(self.hook.caps[cap]), "CONST") for cap in CAPS),
                (SHARED_MODULE, "TB_RAPID_VERSION", "num", str(self.version), "CONST"),
                (SHARED_MODULE, "TB_VERSION", "num", str(FILE_VERSION), "CONST"),
                (SHARED_MODULE, "TB_MAX_CMDS", "num", str(MAX_COMMANDS), "CONST"),
                (SHARED_MODULE, "TB_TOOL_MM", "num", _num(TOOL_MM), "CONST"),
                (SHARED_MODULE, "TB_TOOL_DEG", "num", _num(TOOL_DEG), "CONST"),
                (SHARED_MODULE, "TB_TOOL_DIFFERS", "string", f'"{TOOL_DIFFERS}"', "CONST"),
                (SHARED_MODULE, "TB_V_LEAX_MAX", "num", _num(V_LEAX_MAX), "CONST"),
                (SHARED_MODULE, "TB_WAIT_MAX", "num", _num(WAIT_MAX), "CONST"),
                *((SHARED_MODULE, name, "num", _num(cap), "CONST")
                  for name, cap in ZONE_MAX.values()),
                *((SHARED_MODULE, name, "string", f'"{text}"', "CONST")
                  for name, text in LIMIT_REASONS.items()),
                (SHARED_MODULE, "TB_DIR", "string", '"RAMDISK:"', "CONST"),
                (SHARED_MODULE, "TB_DONE", "string", f'"{DONE}"', "CONST"),
                (SHARED_MODULE, "TB_FAILED", "string", f'"{FAILED}"', "CONST"),
                (ZONES_MODULE, "TB_WZ_FAR", "num", _num(FAR), "CONST"),
                (ZONES_MODULE, "TB_WZ_COUNT", "num", str(len(z.boxes())), "CONST"),
                (ZONES_MODULE, "tb_zones_n", "num", "0", "TASK PERS"),
                (ZONES_MODULE, "tb_zones_at", "string", '""', "TASK PERS"),
                (ZONES_MODULE, "TB_ZONES_ACTIVE", "string", f'"{ZONES_ACTIVE}"', "CONST"),
            ))
            for box in z.boxes():  # the init value [0]: WZLimSup writes the identity
                yield unit.task, (ZONES_MODULE, box.name, "wzstationary", "[0]", "TASK PERS")

    def _module_of(self, task: str) -> dict[str, bool]:
        """Our modules in ``task`` -> whether each is a system module."""
        return {task_module(task): True, ZONES_MODULE: True, SHARED_MODULE: False}

    def _tb_zones(self, task: str) -> None:
        """``tb_zones`` (TestbedZones.sys), run as the POWER_ON event routine of ``task``:
        the count first to 0, each zone's identity and the count as WZLimSup activates
        it, the time stamp, then the ``Testbed Zones Active`` entry; the hook supervises
        the arm's zones from now on."""
        unit = next(u for u in self.hook.units if u.task == task)
        sym = self.controller.symbols
        try:
            sym.find([task, task_module(task), "tb_zone_lo"])
        except Exception:
            raise RapidError(40999, "Event routine failed", task=task,
                             desc=f"tb_zones: {task_module(task)} (the zone constants) is "
                                  "not loaded") from None
        sym.set([task, ZONES_MODULE, "tb_zones_n"], "0")
        sym.set([task, ZONES_MODULE, "tb_zones_at"], '""')
        offset = self.hook.units.index(unit) * len(self.consts[unit.arm].boxes())
        for k, box in enumerate(self.consts[unit.arm].boxes()):
            sym.set([task, ZONES_MODULE, box.name], f"[{offset + k + 1}]")
            sym.set([task, ZONES_MODULE, "tb_zones_n"], str(k + 1))
        self.hook.zones[unit.arm] = self.consts[unit.arm]
        stamp = time.strftime("%Y-%m-%d %H:%M:%S")  # CDate() + " " + CTime()
        sym.set([task, ZONES_MODULE, "tb_zones_at"], f'"{stamp}"')
        n = len(self.consts[unit.arm].boxes())
        self.controller.elog.write(ERRWRITE_INFO, MSG_INFO, ZONES_ACTIVE, src_name=task,
                                   args=(ZONES_ACTIVE, task, f"zones {n}", stamp))

    def set_event_routines(self, configured: bool) -> None:
        """Whether ``tb_zones`` is each task's POWER_ON event routine (system parameters,
        Controller / Event Routine): the install step, or a lab that removed it."""
        routines = self.controller.event_routines
        for unit in self.hook.units:
            er = EventRoutine("POWER_ON", ZONES_ROUTINE, unit.task)
            if configured and er not in routines:
                routines.append(er)
            elif not configured and er in routines:
                routines.remove(er)

    @property
    def event_routines(self) -> bool:
        """Whether every task has ``tb_zones`` as its POWER_ON event routine."""
        return all(EventRoutine("POWER_ON", ZONES_ROUTINE, u.task)
                   in self.controller.event_routines for u in self.hook.units)

    def _restarted(self, mode: str) -> None:
        """A restart erased the stationary zones; Reset RAPID removed our program module
        (a start runs nothing until it is loaded again)."""
        self.hook.zones.clear()
        if mode == "pstart":
            self.loaded = False
            self.controller.on_start = None

    @property
    def zones_active(self) -> dict[str, bool]:
        """Arm -> whether the motion system supervises its zones now (the truth)."""
        return {u.arm: u.arm in self.hook.zones for u in self.hook.units}

    def set_loaded(self, loaded: bool) -> None:
        """Load (declare the symbols, start runs our RAPID) or unload; ``ValueError``
        while a program runs (a controller loads modules with RAPID stopped)."""
        if self.controller.running:
            raise ValueError("RAPID is running: stop it before loading or unloading modules")
        sym = self.controller.symbols
        present = {(u.task, m): sym.has_module(u.task, m)
                   for u in self.hook.units for m in self._module_of(u.task)}
        for task, (module, name, type_name, value, storage) in self.declarations():
            if not loaded:
                sym.undeclare(task, module, name)
            elif not present[(task, module)]:  # a module still loaded keeps its values
                sym.declare(task, module, name, type_name, value, storage)
        for unit in self.hook.units:
            for module, system in self._module_of(unit.task).items():
                sym.declare_module(unit.task, module, system=system)
            if loaded:
                sym.declare_routine(unit.task, ZONES_MODULE, ZONES_ROUTINE, self._tb_zones)
            else:
                sym.undeclare_routine(unit.task, ZONES_MODULE, ZONES_ROUTINE)
        self.loaded = loaded
        self.controller.on_start = self.hook if loaded else None

    def set_version(self, version: int) -> None:
        """What ``TB_RAPID_VERSION`` reads (an older module set on the controller)."""
        if isinstance(version, bool) or not isinstance(version, int) or version < 0:
            raise ValueError(f"rapid_version must be a whole number >= 0, got {version!r}")
        self.version = version
        if self.loaded:
            for unit in self.hook.units:
                self.controller.symbols.declare(unit.task, SHARED_MODULE, "TB_RAPID_VERSION",
                                                "num", str(version), "CONST")

    def lab_state(self) -> dict[str, Any]:
        """For ``GET /lab/controller``: what is installed."""
        return {"loaded": self.loaded, "version": self.version,
                "event_routines": self.event_routines,
                "zones": {u.arm: {"box_mm": list(self.consts[u.arm].box),
                                  "zone_z_mm": self.consts[u.arm].zone_z,
                                  "floor_z_mm": self.consts[u.arm].floor_z,
                                  "active": u.arm in self.hook.zones}
                          for u in self.hook.units}}
