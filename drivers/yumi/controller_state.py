"""What the YuMi's controller says about itself, and whether a push may start.

Why a module of its own: two callers ask the same questions of an IRC5 through Robot Web
Services and must answer them alike. The driver (:class:`~drivers.yumi.yumi_controller.
RwsYumiController`) asks before every program start -- Auto mode, motors on, RAPID
stopped, no task left stopped by a RAPID error -- and refuses with one line naming what
to fix; ``testbed check`` asks for the whole picture (RobotWare, options, serial, tasks,
our RAPID modules and their version, the world zones) through :func:`describe` and fails
on :func:`problems`. A real controller's answers are listed in docs/rws-checklist.md.

Every function takes the ABB client's ``RWS`` object (``abb_robot_client.rws``) or what
it returned; nothing here imports it, so the module loads without the YuMi extra.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

RAPID_VERSION = 3
"""``TB_RAPID_VERSION`` of the robot/rapid/ modules this driver speaks to (TestbedMotion.mod;
tests/drivers/test_yumi_controller_state.py keeps the two equal)."""
REQUIRED_OPTIONS = {"616-1": "PC Interface", "623-1": "Multitasking",
                    "604-": "MultiMove (604-1 Coordinated or 604-2 Independent)",
                    "608-1": "World Zones"}
"""RobotWare options our RAPID and this driver need, by the option number's prefix."""
OPMODE_TEXT = {"AUTO": "automatic", "MANR": "manual, reduced speed",
               "MANF": "manual, full speed"}
CTRLSTATE_FIX = {
    "motoroff": "the motors are off: press the Motors On button on the controller",
    "guardstop": "a guard stop is open (a safety circuit: door, light curtain, enabling "
                 "device): close it, then press Motors On",
    "emergencystop": "an emergency stop is pressed: release it, reset it and press "
                     "Motors On",
    "emergencystopreset": "the emergency stop was released but not reset: reset it and "
                          "press Motors On",
    "sysfail": "the controller is in system failure: read its event log and restart it",
    "init": "the controller is still starting: wait for it",
}
PP_RESET = 10002
"""The event "Program pointer has been reset": what clears a RAPID error's stop."""
OUR_ERRWRITES = range(80001, 80004)
"""Our RAPID's own ``ErrWrite`` entries (80001 refused, 80003 done): refusals of one
program, not a stopped task."""
ZONE_SYMBOLS = ("tb_zone_lo", "tb_zone_hi", "tb_zone_z", "tb_floor_z")
"""The world-zone constants of each task module (robot/rapid/TestbedTask_L.mod)."""
ZONES_MODULE = "TestbedZones"
"""The system module whose POWER_ON routine ``tb_zones`` activates the zones and says so:
``tb_zones_n`` (zones activated at the last power on, of ``TB_WZ_COUNT``) and
``tb_zones_at`` (when), TASK PERS, so they survive PP to Main (issue 29)."""


def one_line(text: object) -> str:
    return " ".join(str(text).split())


def entry_text(e: Any) -> str:
    """One line naming an event log entry: code, title and what it says."""
    args = [a for a in (getattr(e, "args", None) or []) if str(a).strip()]
    if len(args) > 1 and str(args[0]).lower() == str(e.title).lower():  # an ErrWrite's lines
        detail = "; ".join(str(a) for a in args[1:])
    else:
        detail = "; ".join(s for s in (getattr(e, "desc", "") or "",
                                       getattr(e, "causes", "") or "") if s.strip())
        detail = detail or "; ".join(str(a) for a in args)
    return one_line(f"event log {e.code} {e.title!r}: {detail}")


def rapid_error(log: Sequence[Any]) -> Any | None:
    """The error (type 3) that left RAPID stopped, if no program pointer reset came after
    it (``log``: newest first, as ``read_event_log`` gives it); our own refusals
    (:data:`OUR_ERRWRITES`) do not stop a task and do not count."""
    for e in log:
        if e.code == PP_RESET:
            return None
        if e.msgtype >= 3 and e.code not in OUR_ERRWRITES and 40000 <= e.code < 60000:
            return e
    return None


@dataclass(frozen=True, slots=True)
class ControllerState:
    """The four things that decide whether a program may start, plus the speed ratio."""

    opmode: str
    ctrlstate: str
    execstate: str
    speedratio: float | None = None
    rapid_error: str | None = None
    """One line naming the RAPID error that stopped a task (None: none)."""


def read_state(rws: Any, log: Sequence[Any] | None = None) -> ControllerState:
    """Operating mode, controller state, RAPID execution, speed ratio and the error (if
    any) that stopped RAPID, read through ``rws``; ``log``: the event log when the caller
    has just read it (a controller sends the whole log: read it once)."""
    err = rapid_error(rws.read_event_log() if log is None else log)
    try:
        ratio: float | None = float(rws.get_speedratio())
    except Exception:  # an old RobotWare without panel/speedratio: report it unknown
        ratio = None
    return ControllerState(str(rws.get_operation_mode()).upper(),
                           str(rws.get_controller_state()).lower(),
                           str(rws.get_execution_state().ctrlexecstate).lower(), ratio,
                           None if err is None else entry_text(err))


def refusal(state: ControllerState) -> str | None:
    """Why a program must not start now (one line naming what to fix), or None."""
    if state.opmode != "AUTO":
        mode = OPMODE_TEXT.get(state.opmode, state.opmode)
        return (f"the controller is in {mode} mode ({state.opmode}), not automatic: turn "
                f"the key switch to Auto and confirm on the FlexPendant")
    if state.ctrlstate != "motoron":
        fix = CTRLSTATE_FIX.get(state.ctrlstate, "turn the motors on")
        return f"the controller state is {state.ctrlstate}, not motoron: {fix}"
    if state.execstate != "stopped":
        return (f"RAPID is {state.execstate} (a program started from the FlexPendant or "
                f"another client?): stop it first")
    if state.rapid_error is not None:
        return (f"a task was stopped by a RAPID error ({state.rapid_error}): fix its cause, "
                f"then reset the program pointer (PP to Main) on the FlexPendant")
    return None


@dataclass
class ControllerReport:
    """What ``testbed check`` prints of one controller (never a credential)."""

    robotware: str = ""
    system: str = ""
    serial: str = ""
    options: list[str] = field(default_factory=list)
    state: dict[str, Any] = field(default_factory=dict)
    tasks: dict[str, dict[str, Any]] = field(default_factory=dict)
    rapid: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Per motion task: ``version`` (None: our modules are not loaded), ``zones``."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _state_items(doc: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    items = doc.get("_embedded", {}).get("_state", [])
    return [i for i in items if isinstance(i, Mapping)]


def _symbol(rws: Any, task: str, module: str, name: str) -> str | None:
    try:
        return str(rws.get_rapid_variable(f"{module}/{name}", task))
    except Exception:  # NO_SUCH_SYMBOL: the module is not loaded (or is another version)
        return None


def _number(text: str | None) -> float | None:
    try:
        return None if text is None else float(text)
    except ValueError:
        return None


def _pos(text: str | None) -> list[float] | None:
    if text is None:
        return None
    nums = re.findall(r"-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?", text)
    return [float(v) for v in nums[:3]] if len(nums) >= 3 else None


def rapid_of_task(rws: Any, task: str) -> dict[str, Any]:
    """Our modules in ``task``: their version and the world zones they define."""
    side = task.rsplit("_", 1)[-1]
    module = f"TestbedTask_{side}"
    version = _number(_symbol(rws, task, "TestbedMotion", "TB_RAPID_VERSION"))
    zones: dict[str, Any] = {}
    for name in ZONE_SYMBOLS:
        raw = _symbol(rws, task, module, name)
        zones[name] = _pos(raw) if name.endswith(("_lo", "_hi")) else _number(raw)
    active = {"n": _number(_symbol(rws, task, ZONES_MODULE, "tb_zones_n")),
              "of": _number(_symbol(rws, task, ZONES_MODULE, "TB_WZ_COUNT")),
              "at": (_symbol(rws, task, ZONES_MODULE, "tb_zones_at") or "").strip('"')}
    return {"version": None if version is None else int(version), "zones": zones,
            "zones_active": active}


def zones_active_problem(task: str, active: Mapping[str, Any] | None) -> str | None:
    """One line if ``task``'s world zones are not all active (``tb_zones_n`` short of
    ``TB_WZ_COUNT``, or unreadable: TestbedZones.sys not loaded), else None."""
    n, of = (active or {}).get("n"), (active or {}).get("of")
    if n is None or of is None:
        return (f"task {task}: cannot read {ZONES_MODULE}'s tb_zones_n: the system module "
                f"TestbedZones.sys is not loaded, so no world zone is known to be active "
                f"(robot/README.md, 'Install')")
    if n < of:
        return (f"task {task}: the world zones are NOT active ({n:g} of {of:g} activated "
                f"at the last power on): tb_zones failed or is not the POWER_ON event "
                f"routine; read the event log, fix it and restart the controller "
                f"(robot/README.md, 'The zones')")
    return None


def identity_fields(system: Mapping[str, Any], ident: Mapping[str, Any]) -> dict[str, str]:
    """``robotware``, ``system`` and ``serial`` ("" where not said) from the answers to
    ``rw/system`` and ``ctrl/identity`` (either may be ``{}``): what ``testbed check``
    prints and what a run records of its YuMi host, read by one parser."""
    out = {"robotware": "", "system": "", "serial": ""}
    for item in _state_items(system):
        if item.get("_type") == "sys-system-li":
            out["robotware"] = str(item.get("rwversion", ""))
            out["system"] = str(item.get("name", ""))
    for item in _state_items(ident):
        out["serial"] = str(item.get("ctrl-id", ""))
        out["system"] = out["system"] or str(item.get("ctrl-name", ""))
    return out


def describe(rws: Any, tasks: Sequence[str]) -> ControllerReport:
    """The controller as ``testbed check`` shows it: identity, RobotWare and options,
    state, every RAPID task, and our modules in each of ``tasks`` (the arms' tasks)."""
    system = rws._do_get("rw/system")
    rep = ControllerReport(**identity_fields(system, rws._do_get("ctrl/identity")))
    for item in _state_items(system):
        if item.get("_type") == "sys-options-li":
            rep.options = [str(o.get("option", "")) for o in item.get("options", [])]
    rep.state = asdict(read_state(rws))
    for name, t in rws.get_tasks().items():
        rep.tasks[name] = {"type": t.type_, "active": bool(t.active),
                           "excstate": t.excstate, "motion": bool(t.motiontask)}
    for task in tasks:
        rep.rapid[task] = rapid_of_task(rws, task)
    return rep


def problems(rep: Mapping[str, Any], tasks: Sequence[str],
             table_boxes: Mapping[str, Sequence[float]] | None = None,
             travel_z: Mapping[str, float] | None = None) -> list[str]:
    """What must be fixed before a trial, one line each (``rep``: a
    :class:`ControllerReport` as a dict); ``table_boxes``: task -> the calibration's
    ``table_box_mm``, which must lie inside that task's world zone box; ``travel_z``:
    task -> the calibration's ``z_travel_mm``, at or above the zone's ``tb_zone_z`` (a
    travel below it, outside the box, would stop the arm)."""
    out: list[str] = []
    opts = rep.get("options") or []
    for number, name in REQUIRED_OPTIONS.items():
        if not any(str(o).startswith(number) for o in opts):
            out.append(f"RobotWare option {number.rstrip('-')} {name} is missing: our RAPID "
                       f"(robot/rapid/) needs it (robot/README.md)")
    state = ControllerState(**rep.get("state", {}))
    if (why := refusal(state)) is not None:
        out.append(why)
    for task in tasks:
        if task not in rep.get("tasks", {}):
            out.append(f"the controller has no RAPID task {task} (an IRB 14000 has T_ROB_L "
                       f"and T_ROB_R)")
            continue
        ours = rep.get("rapid", {}).get(task, {})
        version = ours.get("version")
        if version is None:
            out.append(f"task {task}: the testbed RAPID modules are not loaded "
                       f"(robot/README.md, 'Install')")
        elif version != RAPID_VERSION:
            out.append(f"task {task}: the testbed RAPID modules are version {version}, this "
                       f"driver needs {RAPID_VERSION}: load robot/rapid/ from this checkout")
        else:
            zones = ours.get("zones", {})
            if "zones_active" in ours and (  # describe() always reads it
                    why := zones_active_problem(task, ours["zones_active"])) is not None:
                out.append(why)
            if (box := (table_boxes or {}).get(task)) is not None:
                out += _zone_problems(task, zones, box)
            z, top = (travel_z or {}).get(task), zones.get("tb_zone_z")
            if z is not None and top is not None and z < top:
                out.append(f"task {task}: the calibration's z_travel_mm {z:g} is below the "
                           f"world zone's tb_zone_z {top:g}: a travel outside the zone box "
                           f"would stop the arm; raise z_travel_mm to {top:g} or more")
    return out


def _zone_problems(task: str, zones: Mapping[str, Any], box: Sequence[float]) -> list[str]:
    lo, hi = zones.get("tb_zone_lo"), zones.get("tb_zone_hi")
    if lo is None or hi is None:
        return [f"task {task}: its world zone box (tb_zone_lo, tb_zone_hi) cannot be read"]
    x0, y0, x1, y1 = (float(v) for v in box)
    if x0 < lo[0] or y0 < lo[1] or x1 > hi[0] or y1 > hi[1]:
        return [f"task {task}: the calibration's table box ({x0:g}, {y0:g}, {x1:g}, {y1:g}) "
                f"mm reaches outside the world zone box ({lo[0]:g}, {lo[1]:g}, {hi[0]:g}, "
                f"{hi[1]:g}): a push there would stop the arm; shrink the table box or "
                f"widen the zone (robot/README.md)"]
    return []

