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

- ``TestbedTask_X``: ``tb_name`` (CONST string), ``tool_pusher`` (TASK PERS tooldata;
  ``tframe`` z = the pusher's length until a program sets it), ``tb_floor_z``,
  ``tb_zone_z`` (CONST num), ``tb_zone_lo`` = ``[x0,y0,0]``, ``tb_zone_hi`` =
  ``[x1,y1,0]`` (CONST pos);
- ``TestbedMotion``: ``TB_RAPID_VERSION``, ``TB_VERSION``, ``TB_MAX_CMDS``,
  ``TB_WZ_FAR`` (CONST num), ``TB_DIR``, ``TB_DONE``, ``TB_FAILED`` (CONST string), and
  the five ``wzstationary`` VARs ``tb_wz_floor``, ``tb_wz_xlo``, ``tb_wz_xhi``,
  ``tb_wz_ylo``, ``tb_wz_yhi`` holding the identity ``WZLimSup`` gave each zone at power
  on (``[0]`` would mean ``tb_zones`` never ran).

Not loaded: none of these symbols, and a start runs nothing (no ``Done`` entry), as on a
controller whose tasks hold other programs.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from sim_twin.rws.irc5 import Irc5Controller
from sim_twin.rws.motion_program import FILE_VERSION
from sim_twin.rws.rapid_data import format_number
from sim_twin.rws.testbed_rapid import (
    DONE,
    FAILED,
    MAX_COMMANDS,
    RAPID_VERSION,
    TestbedRapid,
)
from sim_twin.rws.world_zones import FAR

SHARED_MODULE = "TestbedMotion"
PUSHER_LOAD = "[0.1,[0,0,50],[1,0,0,0],0,0,0]"
"""``tool_pusher``'s load in the task modules (a placeholder until the pushers are weighed)."""
Decl = tuple[str, str, str, str, str]
"""(module, name, type, value, storage)"""


def task_module(task: str) -> str:
    """Our task module of a motion task: ``T_ROB_L`` -> ``TestbedTask_L``."""
    return f"TestbedTask_{task.rsplit('_', 1)[-1]}"


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
        if loaded:
            self.set_loaded(True)
        else:
            controller.on_start = None

    def declarations(self) -> Iterator[tuple[str, Decl]]:
        """(task, declaration) of every symbol our modules put in the tasks."""
        for i, unit in enumerate(self.hook.units):
            z = self.hook.zones[unit.arm]
            mod = task_module(unit.task)
            name = self.hook.program_file(unit.task).split(":", 1)[-1]
            pusher = (f"[TRUE,[[0,0,{_num(self.hook.pusher_length_mm)}],[1,0,0,0]],"
                      f"{PUSHER_LOAD}]")
            yield from ((unit.task, d) for d in (
                (mod, "tb_name", "string", f'"{name}"', "CONST"),
                (mod, "tool_pusher", "tooldata", pusher, "TASK PERS"),
                (mod, "tb_floor_z", "num", _num(z.floor_z), "CONST"),
                (mod, "tb_zone_z", "num", _num(z.zone_z), "CONST"),
                (mod, "tb_zone_lo", "pos", f"[{_num(z.x0)},{_num(z.y0)},0]", "CONST"),
                (mod, "tb_zone_hi", "pos", f"[{_num(z.x1)},{_num(z.y1)},0]", "CONST"),
                (SHARED_MODULE, "TB_RAPID_VERSION", "num", str(self.version), "CONST"),
                (SHARED_MODULE, "TB_VERSION", "num", str(FILE_VERSION), "CONST"),
                (SHARED_MODULE, "TB_MAX_CMDS", "num", str(MAX_COMMANDS), "CONST"),
                (SHARED_MODULE, "TB_WZ_FAR", "num", _num(FAR), "CONST"),
                (SHARED_MODULE, "TB_DIR", "string", '"RAMDISK:"', "CONST"),
                (SHARED_MODULE, "TB_DONE", "string", f'"{DONE}"', "CONST"),
                (SHARED_MODULE, "TB_FAILED", "string", f'"{FAILED}"', "CONST"),
            ))
            for k, box in enumerate(z.boxes()):
                yield unit.task, (SHARED_MODULE, box.name, "wzstationary",
                                  f"[{i * len(z.boxes()) + k + 1}]", "VAR")

    def set_loaded(self, loaded: bool) -> None:
        """Load (declare the symbols, start runs our RAPID) or unload; ``ValueError``
        while a program runs (a controller loads modules with RAPID stopped)."""
        if self.controller.running:
            raise ValueError("RAPID is running: stop it before loading or unloading modules")
        for task, (module, name, type_name, value, storage) in self.declarations():
            if loaded:
                self.controller.symbols.declare(task, module, name, type_name, value, storage)
            else:
                self.controller.symbols.undeclare(task, module, name)
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
                "zones": {u.arm: {"box_mm": list(self.hook.zones[u.arm].box),
                                  "zone_z_mm": self.hook.zones[u.arm].zone_z,
                                  "floor_z_mm": self.hook.zones[u.arm].floor_z}
                          for u in self.hook.units}}
