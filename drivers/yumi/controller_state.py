"""What the YuMi's controller says about itself, and whether a push may start.

Why a module of its own: two callers ask the same questions of an IRC5 through Robot Web
Services and must answer them alike. The driver (:class:`~drivers.yumi.yumi_controller.
RwsYumiController`) asks before every program start -- Auto mode, motors on, RAPID
stopped, no task left stopped by a RAPID error, every task's ``TB_RAPID_VERSION`` the one
it expects (:func:`version_refusal`) -- and refuses with one line naming what to fix;
``testbed check`` asks for the whole picture (RobotWare, options, serial, tasks, our RAPID
modules and their version, the world zones, the tool frame, the TCP speed cap) through
:func:`describe` and fails on :func:`problems`. Whether the zones are on since the last
restart is read from the event log by :mod:`drivers.yumi.zones_proof` (the driver keeps
that proof across reads). A real controller's answers are listed in
docs/rws-checklist.md.

Every function takes the ABB client's ``RWS`` object (``abb_robot_client.rws``) or what
it returned; nothing here imports it, so the module loads without the YuMi extra.

Over 400 lines, on purpose: the driver's refusal and ``testbed check``'s report ask the
same questions of the controller; one module keeps their answers alike (see above).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from drivers.yumi.zones_proof import zones_known, zones_known_problem

RAPID_VERSION = 5
"""``TB_RAPID_VERSION`` of the robot/rapid/ modules this driver speaks to (TestbedMotion.mod;
tests/drivers/test_yumi_controller_state.py keeps the two equal)."""
REQUIRED_OPTIONS = {"616-1": "PC Interface",
                    "604-": "MultiMove (604-1 Coordinated or 604-2 Independent)",
                    "608-1": "World Zones"}
"""RobotWare options our RAPID and this driver need, by the option number's prefix."""
WARNED_OPTIONS = {"623-1": "Multitasking"}
"""Options ``testbed check`` only warns about: no ABB source at hand says whether an IRB
14000's two motion tasks need 623-1 or come with MultiMove (604-x) alone (assumed;
docs/rws-checklist.md's options line settles it on day one)."""
CLEAR_MARGIN_MM = 20.0
"""How far above ``tb_zone_z`` the clear height must be."""
OPMODE_TEXT = {"AUTO": "automatic", "MANR": "manual, reduced speed",
               "MANF": "manual, full speed"}
MOTORS_ON = "switch the motors on on the FlexPendant (QuickSet menu, Motors On)"
"""What a YuMi operator does (its controller is inside the robot: no cabinet button;
the FlexPendant's QuickSet menu holds motors on/off and the operating mode; assumed until
docs/rws-checklist.md's "Operating mode and motors on" line is filled in)."""
CTRLSTATE_FIX = {
    "motoroff": f"the motors are off: {MOTORS_ON}",
    "guardstop": "a guard stop is open (a safety circuit: door, light curtain, enabling "
                 f"device): close it, then {MOTORS_ON}",
    "emergencystop": f"an emergency stop is pressed: release it, reset it and {MOTORS_ON}",
    "emergencystopreset": "the emergency stop was released but not reset: reset it and "
                          f"{MOTORS_ON}",
    "sysfail": "the controller is in system failure: read its event log and restart it",
    "init": "the controller is still starting: wait for it",
}
PP_RESET = 10002
"""The event "Program pointer has been reset": what clears a RAPID error's stop."""
OUR_ERRWRITES = range(80001, 80004)
"""Our RAPID's own ``ErrWrite`` entries (80001 refused, 80003 done): refusals of one
program, not a stopped task."""
TOOL = "tool_pusher"
"""Our RAPID's pusher: a TASK PERS tooldata in each task module, measured on the robot."""
ZONE_SYMBOLS = ("tb_zone_lo", "tb_zone_hi", "tb_zone_z", "tb_floor_z")
"""The world-zone constants of each task module (robot/rapid/TestbedTask_L.mod)."""
ZONES_MODULE = "TestbedZones"
"""The system module whose POWER_ON routine ``tb_zones`` activates the zones and says so:
``tb_zones_n`` (zones activated at the last power on, of ``TB_WZ_COUNT``) and
``tb_zones_at`` (when), TASK PERS, so they survive PP to Main (issue 29)."""


V_TCP_MAX = "tb_v_tcp_max"
"""The TCP speed cap (mm/s) a lab sets in each task module (robot/rapid/TestbedTask_L.mod,
CONST num): our RAPID refuses a program whose speed exceeds it, so a calibration's
``max_speed_mm_s`` above it refuses every program."""
TOOL_MM, TOOL_DEG = 1.0, 0.5
"""How far a calibration's tool may be from ``tool_pusher`` before our RAPID refuses its
programs (translation mm, rotation deg; TestbedMotion.mod's ``tb_header``)."""


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
        return (f"the controller is in {mode} mode ({state.opmode}), not automatic: choose "
                f"Auto on the FlexPendant (QuickSet menu, operating mode; a YuMi has no "
                f"key switch) and confirm it there")
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
            "zones_active": active, "tool": tool_frame(_symbol(rws, task, module, TOOL)),
            "v_tcp_max": _number(_symbol(rws, task, module, V_TCP_MAX))}


def version_refusal(rws: Any, tasks: Sequence[str]) -> str | None:
    """One line unless EVERY task in ``tasks`` reads ``TestbedMotion/TB_RAPID_VERSION``
    equal to :data:`RAPID_VERSION` (read now, over ``rws``: a person may load another
    module with a ``main`` between two pushes, and a start runs whatever ``main`` the task
    holds); else None."""
    for task in tasks:
        got = _number(_symbol(rws, task, "TestbedMotion", "TB_RAPID_VERSION"))
        if got is None:
            return (f"task {task}: TestbedMotion/TB_RAPID_VERSION cannot be read: our RAPID "
                    f"is not what the task holds (another program loaded?); load "
                    f"robot/rapid/ from this checkout (robot/README.md, 'Install')")
        if got != RAPID_VERSION:
            return (f"task {task}: TestbedMotion/TB_RAPID_VERSION is {got:g}, this driver "
                    f"needs {RAPID_VERSION}; load robot/rapid/ from this checkout "
                    f"(robot/README.md, 'Install')")
    return None


def tool_frame(text: str | None) -> dict[str, Any] | None:
    """A ``tooldata`` in RAPID syntax (``[TRUE,[[0,0,184.2],[1,0,0,0]],[0.272,[7.5,...``)
    as ``trans`` (mm), ``rot`` (quaternion w, x, y, z) and ``mass`` (kg); None unreadable."""
    if text is None:
        return None
    nums = [float(v) for v in re.findall(r"-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?", text)]
    if len(nums) < 8:
        return None
    return {"trans": nums[0:3], "rot": nums[3:7], "mass": nums[7]}


def rotation_deg(wxyz: Sequence[float]) -> float:
    """The angle (deg) of the rotation a quaternion (w, x, y, z) makes."""
    n = math.sqrt(sum(float(v) ** 2 for v in wxyz)) or 1.0
    return math.degrees(2 * math.acos(min(1.0, abs(float(wxyz[0])) / n)))


def tool_problem(task: str, tool: Mapping[str, Any] | None, tool_z_mm: float | None
                 ) -> str | None:
    """One line when the calibration's tool (``[0, 0, tool_z_mm]``, no rotation) is not
    the controller's ``tool_pusher`` within :data:`TOOL_MM` / :data:`TOOL_DEG` (every
    program would be refused, 80001), or the controller's cannot be read; else None."""
    if tool is None:
        return (f"task {task}: the controller's tool_pusher cannot be read (TestbedTask "
                f"module not loaded?): the tool frame is not known (robot/README.md, 'The "
                f"tool frame')")
    if tool_z_mm is None:
        return None
    tx, ty, tz = (float(v) for v in tool["trans"])
    off = math.dist((tx, ty, tz), (0.0, 0.0, float(tool_z_mm)))
    turn = rotation_deg(tool["rot"])
    if off <= TOOL_MM and turn <= TOOL_DEG:
        return None
    return (f"task {task}: the calibration's tool_z_mm {tool_z_mm:g} is not the controller's "
            f"tool_pusher ([{tx:g},{ty:g},{tz:g}], turned {turn:.2f} deg): {off:.1f} mm "
            f"apart (allowed {TOOL_MM:g} mm, {TOOL_DEG:g} deg); our RAPID refuses every "
            f"program; measure the pusher (FlexPendant 4-point TCP) and write the one "
            f"value into tool_pusher and tool_z_mm (robot/README.md, 'The tool frame')")


def speed_problem(task: str, cap: float | None, max_speed_mm_s: float | None
                  ) -> str | None:
    """One line when the controller's TCP speed cap (``tb_v_tcp_max``, mm/s) cannot be
    read (modules older than the cap: nothing on the controller bounds a file's speed)
    or is below the calibration's ``max_speed_mm_s`` (our RAPID refuses every program
    whose speed exceeds it); else None."""
    if cap is None:
        return (f"task {task}: the controller's {V_TCP_MAX} (the TCP speed cap, mm/s) "
                f"cannot be read: the task module is older than the cap; load robot/rapid/ "
                f"from this checkout (robot/README.md, 'Install')")
    if max_speed_mm_s is not None and float(max_speed_mm_s) > cap:
        return (f"task {task}: the calibration's max_speed_mm_s {float(max_speed_mm_s):g} "
                f"is above the controller's {V_TCP_MAX} {cap:g} mm/s: our RAPID refuses "
                f"every program; lower max_speed_mm_s to {cap:g} or less")
    return None


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


def describe(rws: Any, tasks: Sequence[str], log: Sequence[Any] | None = None
             ) -> ControllerReport:
    """The controller as ``testbed check`` shows it: identity, RobotWare and options,
    state, every RAPID task, and our modules in each of ``tasks`` (the arms' tasks);
    ``log``: the event log as just read (None: read here). Each task's ``zones_known``
    is the log's alone (:func:`zones_known`); the driver puts its kept proof in its place
    where the log no longer shows it (``RwsYumiController.describe``)."""
    system = rws._do_get("rw/system")
    rep = ControllerReport(**identity_fields(system, rws._do_get("ctrl/identity")))
    for item in _state_items(system):
        if item.get("_type") == "sys-options-li":
            rep.options = [str(o.get("option", "")) for o in item.get("options", [])]
    log = rws.read_event_log() if log is None else log
    rep.state = asdict(read_state(rws, log))
    for name, t in rws.get_tasks().items():
        rep.tasks[name] = {"type": t.type_, "active": bool(t.active),
                           "excstate": t.excstate, "motion": bool(t.motiontask)}
    for task in tasks:
        rep.rapid[task] = {**rapid_of_task(rws, task), "zones_known": zones_known(log, task)}
    return rep


def option_warnings(rep: Mapping[str, Any]) -> list[str]:
    """``testbed check``'s WARN lines: options that may be needed (:data:`WARNED_OPTIONS`)."""
    opts = rep.get("options") or []
    return [f"RobotWare option {number} {name} is not listed: assumed not needed by an IRB "
            f"14000 with MultiMove; if both arms do not start together, add it "
            f"(docs/rws-checklist.md, options line)"
            for number, name in WARNED_OPTIONS.items()
            if not any(str(o).startswith(number) for o in opts)]


def problems(rep: Mapping[str, Any], tasks: Sequence[str],
             table_boxes: Mapping[str, Sequence[float]] | None = None,
             travel_z: Mapping[str, float] | None = None,
             clear_z: Mapping[str, float] | None = None,
             tool_z: Mapping[str, float] | None = None,
             max_speed: Mapping[str, float] | None = None) -> list[str]:
    """What must be fixed before a trial, one line each (``rep``: a
    :class:`ControllerReport` as a dict); ``table_boxes``: task -> the calibration's
    ``table_box_mm``, which must lie inside that task's world zone box; ``travel_z``:
    task -> the calibration's ``z_travel_mm``, at or above the zone's ``tb_zone_z`` (a
    travel below it, outside the box, would stop the arm); ``clear_z``: its
    ``z_clear_mm``, at least ``tb_zone_z`` + :data:`CLEAR_MARGIN_MM`; ``tool_z``: its
    ``tool_z_mm``, which must be the controller's ``tool_pusher``; ``max_speed``: its
    ``max_speed_mm_s``, at most the task's ``tb_v_tcp_max`` (:func:`speed_problem`)."""
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
            if "zones_known" in ours and (why := zones_known_problem(
                    task, ours["zones_known"], (ours.get("zones_active") or {}).get("of"))):
                out.append(why)
            if "tool" in ours and (why := tool_problem(task, ours["tool"],
                                                       (tool_z or {}).get(task))):
                out.append(why)
            if "v_tcp_max" in ours and (why := speed_problem(
                    task, ours["v_tcp_max"], (max_speed or {}).get(task))):
                out.append(why)
            out += _height_problems(task, zones, (travel_z or {}).get(task),
                                    (clear_z or {}).get(task))
            if (box := (table_boxes or {}).get(task)) is not None:
                out += _zone_problems(task, zones, box)
    return out


def _height_problems(task: str, zones: Mapping[str, Any], travel: float | None,
                     clear: float | None) -> list[str]:
    """Travel height at or above ``tb_zone_z``; clear height (where the joint moves to
    and from rest end) :data:`CLEAR_MARGIN_MM` above it."""
    top = zones.get("tb_zone_z")
    if top is None:
        return []
    out = []
    if travel is not None and travel < top:
        out.append(f"task {task}: the calibration's z_travel_mm {travel:g} is below the "
                   f"world zone's tb_zone_z {top:g}: a travel outside the zone box would "
                   f"stop the arm; raise z_travel_mm to {top:g} or more")
    if clear is not None and clear < top + CLEAR_MARGIN_MM:
        out.append(f"task {task}: the calibration's z_clear_mm {clear:g} is less than "
                   f"{CLEAR_MARGIN_MM:g} mm above the world zone's tb_zone_z {top:g}: the "
                   f"joint moves to and from rest end there (drivers/yumi/paths.py); raise "
                   f"z_clear_mm to {top + CLEAR_MARGIN_MM:g} or more")
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

