"""The twin's IRC5 controller: operating mode, controller state, RAPID execution and
tasks, with the stores RWS reads (symbols, signals, files, event log, mechanical units).

Why it exists: the ABB clients decide what to do from the controller's state (a motion
program is started only when execution is ``stopped`` and the state ``motoron``) and a
real controller refuses what its state does not allow. This model holds that state,
answers every action as the controller does (or as docs/rws-checklist.md says the twin
assumes it does), and is settable from the twin's side (:meth:`Irc5Controller.set_state`,
:meth:`Irc5Controller.task_error`; over HTTP: ``POST /lab/controller``).

The rules (each a line of docs/rws-checklist.md):

- RAPID mastership (start, resetpp, task (de)activation, a symbol's value) is granted to
  a remote client in ``AUTO`` only; in manual mode (``MANR``, ``MANF``) it needs RMMP, which
  the twin does not model, so those are refused (400, the manual's mastership example).
- ``start`` also needs ``motoron`` and execution ``stopped``; ``resetpp`` and task
  (de)activation need execution ``stopped``.
- Leaving ``motoron`` (motors off, guard stop, emergency stop) or changing the operating
  mode stops a running program; a new operating mode turns the motors off.
- A RAPID error (:meth:`task_error`, or a :class:`RapidError` from the start hook) writes
  an error entry (type 3) to the event log and stops the task and the execution.
- ``resetpp`` (PP to Main) also sets every ``VAR`` of the active tasks back to its
  declared value, as RAPID does; PERS and CONST keep theirs.
- :meth:`restart` (``POST ctrl?action=restart``, ``restart-mode=restart|pstart``): the
  event log gets 10045 "System restarted" first (its description names the mode: a
  restart or "Reset RAPID"; :data:`RESTARTED`), then a restart erases the stationary
  world zones (:attr:`on_restart` hooks), stops RAPID,
  leaves the motors off; ``pstart`` ("Reset RAPID") also removes every PROGRAM module
  (system modules stay); then the configured POWER_ON event routines
  (:attr:`event_routines`) run in their tasks, and one whose routine no loaded module
  holds is an error entry (:data:`EVENT_ROUTINE_MISSING`), as on a controller whose
  event routine lived in a program module that Reset RAPID removed. Every TASK PERS
  and PERS keeps its value through both (only a removed module's symbols are gone).
- ``omit_motiontask``: ``GET rw/rapid/tasks`` leaves the ``motiontask`` field out, as some
  controllers do (abb_motion_program_exec issue 4). abb_robot_client's ``get_tasks()``
  then reads every task as not a motion task, so its ``start()`` activates and
  deactivates nothing: every task that is active starts and runs what it holds.

The seam for the motion (the later RAPID-semantics work): ``on_start(run)`` is called in
a thread of its own after every accepted ``start``; execution reads ``running`` until it
returns (or ``stop`` is called: then ``run.stop_requested`` is set and execution reads
``stopped`` at once; the hook should return soon). It may read the uploaded files
(``controller.files``), signals, symbols, write the event log, and raise
:class:`RapidError` for a RAPID error. Without a hook a start ends at once.

Over 450 lines, on purpose: one controller's state (mode, motors, RAPID execution,
tasks, event log, the stores RWS reads): every action reads and changes the same state,
as the real controller's do.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from sim_twin.rws.errors import EXEC_STATE, GENERIC, MASTER_REJECT, MODE_REJECT, refused
from sim_twin.rws.event_log import MSG_ERROR, MSG_INFO, EventLog
from sim_twin.rws.file_store import FileStore
from sim_twin.rws.io_signals import Signal, SignalTable
from sim_twin.rws.mechunits import (
    YUMI_UNITS,
    MechUnit,
    PoseSource,
    StaticPoses,
    jointtarget_item,
    robtarget_item,
    unit_by_name,
)
from sim_twin.rws.rapid_data import SymbolTable

OPMODES = ("INIT", "AUTO_CH", "MANF_CH", "MANR", "MANF", "AUTO", "UNDEF")
CTRLSTATES = ("init", "motoron", "motoroff", "guardstop", "emergencystop",
              "emergencystopreset", "sysfail")
START_FIELDS = ("regain", "execmode", "cycle", "condition", "stopatbp", "alltaskbytsp")
HOOK_FAILED = 40000
"""The twin's own code for a start hook that failed with something else than a
:class:`RapidError` (a bug in the twin, not a RAPID error)."""
EVENT_ROUTINE_MISSING = 40999
"""The twin's OWN code for "an event routine names a routine no loaded module holds"
(RAPID domain): RobotWare's event for it was not in any manual the search tool had;
docs/rws-checklist.md asks for the real one."""
RESTART_MODES = {"restart": "Restart", "pstart": "Reset RAPID"}
"""The restart modes the twin models (RWS ``restart-mode``; the FlexPendant's names)."""
RESTARTED = (10045, "System restarted")
"""The entry every restart writes first (info; code 10045, operational, listed in
``rw/elog/0`` with every other): RobotWare's "System restarted". That a controller
writes it for "Reset RAPID" too, with the mode in its description, is assumed
(docs/rws-checklist.md asks)."""
STATE_EVENTS = {
    "motoron": (10011, "Motors ON state", "The system is in the Motors ON state."),
    "motoroff": (10010, "Motors OFF state", "The system is in the Motors OFF state."),
    "guardstop": (10012, "Safety guard stop state",
                  "The system is in the guard stop state: a safety circuit is open."),
    "emergencystop": (10013, "Emergency stop state",
                      "The system is in the emergency stop state."),
}


class RapidError(Exception):
    """A RAPID run-time error in a task: what the event log shows."""

    def __init__(self, code: int, title: str, *, task: str | None = None, desc: str = "",
                 causes: str = "", actions: str = "", args: Sequence[object] = (),
                 msgtype: int = MSG_ERROR) -> None:
        super().__init__(f"{code} {title}")
        self.code, self.title, self.task, self.desc = int(code), title, task, desc
        self.causes, self.actions, self.args, self.msgtype = causes, actions, args, msgtype


@dataclass
class TaskState:
    name: str
    motion: bool = True
    active: bool = True
    excstate: str = "ready"
    """ready | started | stopped | uninitialized"""

    def item(self, list_item: bool, motiontask: bool = True) -> dict[str, Any]:
        """The task as RWS lists it; ``motiontask`` False leaves that field out."""
        out = {"_type": "rap-task-li" if list_item else "rap-task", "_title": self.name,
               "name": self.name, "type": "norm", "taskstate": "linked",
               "excstate": self.excstate, "active": "On" if self.active else "Off",
               "motiontask": "TRUE" if self.motion else "FALSE"}
        if not motiontask:
            del out["motiontask"]
        return out


@dataclass
class ProgramRun:
    """One accepted ``start``: what the hook gets."""

    run_id: int
    tasks: tuple[str, ...]
    cycle: str
    controller: Irc5Controller
    stop_requested: threading.Event = field(default_factory=threading.Event)


StartHook = Callable[[ProgramRun], None]
RestartHook = Callable[[str], None]
"""Called with the restart mode, before the event routines run (e.g. the world zones
the motion system forgets at a restart)."""


@dataclass(frozen=True)
class EventRoutine:
    """One instance of system parameters Controller / Event Routine (CAB_EXEC_HOOKS)."""

    event: str
    routine: str
    task: str


@dataclass
class Identity:
    name: str = "YUMI_TWIN"
    ctrl_id: str = "14000-500000"
    ctrl_type: str = "Virtual Controller"
    rwversion: str = "6.08.01.00"
    sysid: str = "{5C1D3A2B-0000-4000-8000-000000014000}"
    options: tuple[str, ...] = ("RobotWare Base", "English", "608-1 World Zones",
                                "616-1 PC Interface", "623-1 Multitasking",
                                "604-1 MultiMove Coordinated", "IRB 14000")


class Irc5Controller:
    """The state model. Thread-safe: the HTTP threads, the lab and the program run share
    it under one lock (never held while the start hook runs)."""

    def __init__(self, *, units: Sequence[MechUnit] = YUMI_UNITS,
                 poses: PoseSource | None = None, extra_tasks: Iterable[str] = (),
                 signals: Iterable[Signal] | None = None, files: FileStore | None = None,
                 on_start: StartHook | None = None, opmode: str = "AUTO",
                 ctrlstate: str = "motoron", speedratio: int = 100,
                 identity: Identity | None = None, omit_motiontask: bool = False) -> None:
        self._lock = threading.RLock()
        self._changed = threading.Condition(self._lock)
        self.units = {u.name.upper(): u for u in units}
        self.poses: PoseSource = poses if poses is not None else StaticPoses(units)
        self.tasks = {u.task: TaskState(u.task) for u in units}
        self.tasks.update({t: TaskState(t, motion=False) for t in extra_tasks})
        self.symbols = SymbolTable(u.task for u in units)
        self.signals = SignalTable(signals)
        self.files = files if files is not None else FileStore()
        self.elog = EventLog()
        self.identity = identity or Identity()
        self.on_start = on_start
        self.omit_motiontask = bool(omit_motiontask)
        """``GET rw/rapid/tasks`` without the ``motiontask`` field (see the module)."""
        self.event_routines: list[EventRoutine] = []
        self.on_restart: list[RestartHook] = []
        self._check(opmode=opmode, ctrlstate=ctrlstate, speedratio=speedratio)
        self.opmode, self.ctrlstate, self.speedratio = opmode, ctrlstate, int(speedratio)
        self.cycle, self._once_done = "forever", False
        self._run: ProgramRun | None = None
        self._serial = 0
        self._log_opmode(opmode)
        self._log_ctrlstate(ctrlstate)

    # --- reads --------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        with self._lock:
            return self._run is not None

    def execution_item(self) -> dict[str, Any]:
        with self._lock:
            cycle = "oncedone" if self.cycle == "once" and self._once_done else self.cycle
            return {"_type": "rap-execution", "_title": "execution",
                    "ctrlexecstate": "running" if self._run else "stopped", "cycle": cycle}

    def task_item(self, task: TaskState, list_item: bool) -> dict[str, Any]:
        """``task`` as ``GET rw/rapid/tasks`` answers it on this controller."""
        return task.item(list_item, motiontask=not self.omit_motiontask)

    def task(self, name: str) -> TaskState:
        with self._lock:
            t = self.tasks.get(name) or next((v for k, v in self.tasks.items()
                                              if k.upper() == name.upper()), None)
        if t is None:
            raise refused(404, GENERIC, f"no RAPID task {name!r}")
        return t

    def robtarget(self, unit: str, tool: str, wobj: str, coordinate: str) -> dict[str, Any]:
        u = unit_by_name(self.units, unit)
        t = self.symbols.find_typed(u.task, tool, "tooldata")
        w = self.symbols.find_typed(u.task, wobj, "wobjdata")
        if t is None or w is None:
            missing = tool if t is None else wobj
            raise refused(400, GENERIC, f"no {'tooldata' if t is None else 'wobjdata'} "
                                        f"{missing!r} in task {u.task}")
        return robtarget_item(u, self.poses, t.value, w.value, coordinate)

    def jointtarget(self, unit: str) -> dict[str, Any]:
        return jointtarget_item(unit_by_name(self.units, unit), self.poses)

    def snapshot(self) -> dict[str, Any]:
        """The whole state (the lab side channel's ``GET /lab/controller``)."""
        with self._lock:
            return {"opmode": self.opmode, "ctrlstate": self.ctrlstate,
                    "speedratio": self.speedratio,
                    "execution": "running" if self._run else "stopped",
                    "cycle": self.execution_item()["cycle"],
                    "tasks": {n: {"active": t.active, "excstate": t.excstate,
                                  "motion": t.motion} for n, t in self.tasks.items()},
                    "elog_newest": self.elog.newest}

    def wait_stopped(self, timeout: float) -> bool:
        """Block until execution is stopped (tests, the lab); False on timeout."""
        with self._changed:
            return self._changed.wait_for(lambda: self._run is None, timeout)

    # --- RAPID execution ------------------------------------------------------------------
    def _need_mastership(self, what: str) -> None:
        if self.opmode != "AUTO":
            raise refused(400, GENERIC, f"{what} needs RAPID mastership; a remote client "
                          f"gets it in AUTO only (the controller is in {self.opmode}; "
                          f"manual mode needs RMMP) [new_code {MASTER_REJECT & 0xFFFFFFFF:#x}]")

    def start(self, form: Mapping[str, str]) -> ProgramRun:
        missing = [k for k in START_FIELDS if k not in form]
        if missing:
            raise refused(400, GENERIC, f"action=start needs {', '.join(missing)}")
        if form["cycle"] not in ("forever", "asis", "once"):
            raise refused(400, GENERIC, f"cycle={form['cycle']!r}")
        with self._lock:
            self._need_mastership("start")
            if self._run is not None:
                raise refused(400, EXEC_STATE, "RAPID is already running")
            if self.ctrlstate != "motoron":
                raise refused(400, GENERIC, f"start needs motors on (the controller state "
                                            f"is {self.ctrlstate})")
            tasks = tuple(t.name for t in self.tasks.values() if t.active)
            if not tasks:
                raise refused(400, GENERIC, "no RAPID task is active")
            self._serial += 1
            run = ProgramRun(self._serial, tasks, form["cycle"], self)
            self._run = run
            if form["cycle"] != "asis":
                self.cycle = form["cycle"]
            self._once_done = False
            for t in tasks:
                self.tasks[t].excstate = "started"
            self._changed.notify_all()
            hook = self.on_start
        if hook is None:
            self._finish(run)
        else:
            threading.Thread(target=self._run_hook, args=(hook, run), daemon=True,
                             name=f"rws-program-{run.run_id}").start()
        return run

    def _run_hook(self, hook: StartHook, run: ProgramRun) -> None:
        try:
            hook(run)
        except RapidError as e:
            self.task_error(e.task or run.tasks[0], e.code, e.title, desc=e.desc,
                            causes=e.causes, actions=e.actions, args=e.args,
                            msgtype=e.msgtype)
        except Exception as e:
            self.task_error(run.tasks[0], HOOK_FAILED, "Twin execution hook failed",
                            desc=f"{type(e).__name__}: {e}")
        finally:
            self._finish(run)

    def _finish(self, run: ProgramRun, stopped: bool = False) -> None:
        """End ``run`` (if it is still the current one): execution stopped."""
        with self._lock:
            if self._run is not run:
                return
            run.stop_requested.set()
            self._run = None
            self._once_done = self.cycle == "once" and not stopped
            for t in run.tasks:
                if self.tasks[t].excstate == "started":
                    self.tasks[t].excstate = "stopped"
            self._changed.notify_all()

    def stop(self, form: Mapping[str, str]) -> None:
        if form.get("stopmode", "stop") not in ("cycle", "instr", "stop", "qstop"):
            raise refused(400, GENERIC, f"stopmode={form['stopmode']!r}")
        if form.get("usetsp", "normal") not in ("normal", "alltsk"):
            raise refused(400, GENERIC, f"usetsp={form['usetsp']!r}")
        with self._lock:
            if self._run is not None:
                self._finish(self._run, stopped=True)

    def resetpp(self) -> None:
        with self._lock:
            self._need_mastership("resetpp")
            if self._run is not None:
                raise refused(400, EXEC_STATE, "resetpp while RAPID is running")
            for t in self.tasks.values():
                if t.active:
                    t.excstate = "ready"
                    self.symbols.reset_vars(t.name)  # PP to Main: VARs to their init
                    self.elog.write(10002, MSG_INFO, "Program pointer has been reset",
                                    desc=f"The program pointer of task {t.name} has been "
                                         "reset.", args=(t.name,))

    # --- restarts and event routines ------------------------------------------------------
    def restart(self, mode: str = "restart") -> None:
        """A controller restart (``restart``) or "Reset RAPID" (``pstart``): the
        :data:`RESTARTED` entry, RAPID stops, the motors are off after it, the
        :attr:`on_restart` hooks run (the stationary world zones are erased), ``pstart``
        removes the program modules, then the POWER_ON event routines run. PERS and TASK
        PERS keep their values. ``ValueError`` for a mode the twin does not model."""
        if mode not in RESTART_MODES:
            raise ValueError(f"restart-mode {mode!r}: the twin models "
                             f"{', '.join(RESTART_MODES)}")
        with self._lock:
            self.elog.write(RESTARTED[0], MSG_INFO, RESTARTED[1], src_name="SYS",
                            desc=f"The system has been restarted ({RESTART_MODES[mode]}).",
                            args=(RESTART_MODES[mode],))
            self._stop_current()
            for hook in list(self.on_restart):
                hook(mode)
            if mode == "pstart":
                self.symbols.drop_program_modules()
            for t in self.tasks.values():
                t.excstate = "ready"
            if self.ctrlstate == "motoron":
                self.ctrlstate = "motoroff"
                self._log_ctrlstate("motoroff")
            self._changed.notify_all()
        self.run_event_routines("POWER_ON")

    def run_event_routines(self, event: str) -> None:
        """Run every configured event routine of ``event`` in its task, as RAPID does at
        that event; a routine no loaded module holds is an error entry in its task."""
        for er in [e for e in self.event_routines if e.event == event]:
            routine = self.symbols.routine(er.task, er.routine)
            if routine is None:
                self.elog.write(
                    EVENT_ROUTINE_MISSING, MSG_ERROR, "Event routine not found",
                    desc=f"Task {er.task}: the {event} event routine {er.routine} is in no "
                         "loaded module (a program module removed by Reset RAPID?).",
                    actions="Load the module that holds it, as a system module, and "
                            "restart.", args=(er.task, er.routine, event), src_name=er.task)
                continue
            try:
                routine.body(er.task)
            except RapidError as e:
                self.elog.write(e.code, e.msgtype, e.title, desc=e.desc, args=e.args,
                                src_name=er.task)

    def set_task_active(self, name: str | None, active: bool) -> None:
        """``rw/rapid/tasks/<name>?action=(de)activate``; ``None``: every task."""
        with self._lock:
            targets = list(self.tasks.values()) if name is None else [self.task(name)]
            self._need_mastership("activate" if active else "deactivate")
            if self._run is not None:
                raise refused(400, EXEC_STATE, "the task selection cannot change while "
                                               "RAPID is running")
            for t in targets:
                t.active = active

    def set_symbol(self, parts: Sequence[str], value: str) -> None:
        """``rw/rapid/symbol/data/RAPID/...?action=set``: needs RAPID mastership."""
        with self._lock:
            self._need_mastership("setting a RAPID symbol")
            self.symbols.set(parts, value)

    # --- panel ------------------------------------------------------------------------------
    def request_ctrlstate(self, form: Mapping[str, str]) -> None:
        """``rw/panel/ctrlstate?action=setctrlstate`` (``ctrl-state=motoron|motoroff``)."""
        want = form.get("ctrl-state", "")
        if want not in ("motoron", "motoroff"):
            raise refused(400, GENERIC, f"ctrl-state={want!r} (motoron or motoroff)")
        with self._lock:
            if self.opmode != "AUTO":
                raise refused(400, MODE_REJECT, "motors on/off from a remote client needs AUTO")
            if self.ctrlstate not in ("motoron", "motoroff"):  # a safety stop holds them
                raise refused(400, GENERIC, f"the motors cannot change in state "
                                            f"{self.ctrlstate}")
            self.set_state(ctrlstate=want)

    def request_speedratio(self, form: Mapping[str, str]) -> None:
        try:
            v = float(form.get("speed-ratio", ""))
        except ValueError:
            raise refused(400, GENERIC, "speed-ratio must be a number 0..100") from None
        if not 0 <= v <= 100 or v != int(v):
            raise refused(400, GENERIC, f"speed-ratio={v:g} (a whole number 0..100)")
        with self._lock:
            if self.opmode != "AUTO":
                raise refused(403, MODE_REJECT, "the speed ratio is set in AUTO only")
            self.speedratio = int(v)

    # --- the twin's side: states, RAPID errors ----------------------------------------------
    @staticmethod
    def _check(opmode: str | None = None, ctrlstate: str | None = None,
               speedratio: float | None = None, execution: str | None = None) -> None:
        if opmode is not None and opmode not in OPMODES:
            raise ValueError(f"opmode must be one of {OPMODES}, got {opmode!r}")
        if ctrlstate is not None and ctrlstate not in CTRLSTATES:
            raise ValueError(f"ctrlstate must be one of {CTRLSTATES}, got {ctrlstate!r}")
        if speedratio is not None and not 0 <= speedratio <= 100:
            raise ValueError(f"speedratio must be in 0..100, got {speedratio!r}")
        if execution is not None and execution not in ("running", "stopped"):
            raise ValueError(f"execution must be running or stopped, got {execution!r}")

    def set_state(self, *, opmode: str | None = None, ctrlstate: str | None = None,
                  speedratio: int | None = None, execution: str | None = None) -> None:
        """What the cell does to the controller: the key switch (``opmode``), the motors,
        the safety chain (``ctrlstate``), a program started elsewhere (``execution``).
        Applied in that order; ``ValueError`` (nothing changed) if a value is unknown or
        a program would run without motors on."""
        self._check(opmode, ctrlstate, speedratio, execution)
        with self._lock:
            final = ctrlstate or ("motoroff" if opmode and opmode != self.opmode
                                  else self.ctrlstate)
            if execution == "running" and final != "motoron":
                raise ValueError("a program runs only with the motors on (ctrlstate motoron)")
            if opmode is not None and opmode != self.opmode:
                self._stop_current()
                self.opmode = opmode
                self._log_opmode(opmode)
                if ctrlstate is None:
                    ctrlstate = "motoroff"
            if ctrlstate is not None and ctrlstate != self.ctrlstate:
                if ctrlstate != "motoron":
                    self._stop_current()
                self.ctrlstate = ctrlstate
                self._log_ctrlstate(ctrlstate)
            if speedratio is not None:
                self.speedratio = int(speedratio)
            if execution == "stopped":
                self._stop_current()
            elif execution == "running" and self._run is None:
                self._serial += 1
                tasks = tuple(t.name for t in self.tasks.values() if t.active)
                self._run = ProgramRun(self._serial, tasks, self.cycle, self)
                for t in tasks:
                    self.tasks[t].excstate = "started"
            self._changed.notify_all()

    def set_options(self, options: Sequence[str]) -> None:
        """What ``rw/system/options`` lists (the twin's side: a system built without an
        option, e.g. no ``608-1 World Zones``); ``ValueError`` unless a list of texts."""
        if isinstance(options, str) or not all(isinstance(o, str) and o for o in options):
            raise ValueError("options must be a list of option names")
        with self._lock:
            self.identity = replace(self.identity, options=tuple(options))

    def remove_option(self, option: str) -> None:
        """Drop every option named ``option`` or starting with it and a space (``608-1``
        drops ``608-1 World Zones``); ``ValueError`` if none is listed."""
        with self._lock:
            keep = tuple(o for o in self.identity.options
                         if o != option and not o.startswith(f"{option} "))
            if not option or len(keep) == len(self.identity.options):
                raise ValueError(f"no option {option!r} in {list(self.identity.options)}")
            self.identity = replace(self.identity, options=keep)

    def _stop_current(self) -> None:
        if self._run is not None:
            self._finish(self._run, stopped=True)

    def task_error(self, task: str, code: int, title: str, *, desc: str = "",
                   causes: str = "", actions: str = "", args: Sequence[object] = (),
                   msgtype: int = MSG_ERROR) -> int:
        """A RAPID error in ``task``: an event log entry, the task and execution stopped.
        Returns the entry's sequence number."""
        with self._lock:
            t = self.task(task)
            entry = self.elog.write(code, msgtype, title, desc=desc, causes=causes,
                                    actions=actions, args=args, src_name=t.name)
            if msgtype == MSG_ERROR:
                t.excstate = "stopped"
                self._stop_current()
            return entry.seqnum

    def _log_opmode(self, opmode: str) -> None:
        if opmode in ("MANR", "MANF"):
            speed = "reduced" if opmode == "MANR" else "full"
            self.elog.write(10015, MSG_INFO, "Manual mode selected",
                            desc=f"The system is in manual mode ({speed} speed).",
                            src_name="SYS")
        elif opmode == "AUTO":
            self.elog.write(10016, MSG_INFO, "Automatic mode requested",
                            desc="The system has been ordered to go to automatic mode.",
                            src_name="SYS")
            self.elog.write(10017, MSG_INFO, "Automatic mode confirmed",
                            desc="The system is in automatic mode.", src_name="SYS")

    def _log_ctrlstate(self, ctrlstate: str) -> None:
        if ctrlstate in STATE_EVENTS:
            code, title, desc = STATE_EVENTS[ctrlstate]
            self.elog.write(code, MSG_INFO, title, desc=desc, src_name="SYS")
