"""What goes wrong in a YuMi cell, and what a person does about it: the twin's faults.

Why it exists: a rehearsal must show that a trial survives the stops a lab meets on a
real YuMi (issue 29, point 5) and that a person can clear them where they stand: at the
FlexPendant, at the cabinet, at the cell. So the hardware twin can be put into each of
these states through its lab side channel (``POST /lab/fault``), and cleared by the
person's own actions (``POST /lab/clear``), never by the controller's client:

========== ====================================== ====================================
kind       injected (what the controller shows)    cleared (what the person does)
========== ====================================== ====================================
guard_stop ctrlstate ``guardstop`` (a door opened)  closes the guard (``motoroff``),
                                                   presses Motors On (``motoron``)
motors_off ctrlstate ``motoroff``                   presses Motors On
rapid_error the task's RAPID error in the event log PP to Main (a program pointer reset)
           (40223 "Execution error"), task stopped
zone_stop  the world-zone error our RAPID's zones   jogs the TCP out of the zone (above
           raise (the twin's ``WORLD_ZONE_CODE``),  ``tb_zone_z``, if it is below), then
           the task and execution stopped          PP to Main
camera_frozen the camera sends the same JPEG again  the camera restarts: fresh frames of
           and again (an encoder that hung)         the cell as it is now
========== ====================================== ====================================

Each is what the controller itself would show (its state, its event log codes and
titles), so the driver reads it exactly as it reads a real one. A lost SSH link is the
lab's network, not the twin's: ``testbed.lab.fault_drills`` stops the host's sshd.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from typing import Any, Protocol

from sim_twin.rws.irc5 import Irc5Controller
from sim_twin.rws.testbed_rapid import WORLD_ZONE_CODE, WORLD_ZONE_TITLE

KINDS = ("guard_stop", "motors_off", "rapid_error", "zone_stop", "camera_frozen")
RAPID_ERROR = (40223, "Execution error")
"""A RAPID run-time error as the event log titles it (the one
tests/testbed/test_controller_states.py also raises)."""
JOG_ABOVE_MM = 20.0
"""How far above ``tb_zone_z`` the person jogs a TCP left inside a zone."""


class Freezable(Protocol):
    """What a frozen camera needs of the twin's frame cache (``FrameCache``)."""

    def freeze(self, on: bool) -> None: ...


class Cell(Protocol):
    """What jogging an arm needs of the cell (``YumiTwinCell``)."""

    def tcp_xyz(self) -> Mapping[str, tuple[float, float, float]]: ...

    def halt(self, points: Mapping[str, tuple[float, float, float]]) -> None: ...


class TwinFaults:
    """The faults active on one twin (at most one of each kind) and their clearing.

    ``tasks``: arm -> its RAPID task (``T_ROB_L``); ``zone_z``: arm -> its zone's
    ``tb_zone_z`` (mm); ``publish``: re-render the camera (after a jog or an unfreeze),
    called with ``cell_lock`` held."""

    def __init__(self, controller: Irc5Controller, frames: Freezable, cell: Cell,
                 cell_lock: threading.Lock, tasks: Mapping[str, str],
                 zone_z: Mapping[str, float], publish: Callable[[], None]) -> None:
        self.controller, self.frames, self.cell = controller, frames, cell
        self.cell_lock, self.tasks, self.zone_z = cell_lock, dict(tasks), dict(zone_z)
        self.publish = publish
        self.active: dict[str, str | None] = {}
        """kind -> the arm it names (None: the whole controller or the camera)."""
        self._lock = threading.Lock()

    def inject(self, kind: str, arm: str | None = None) -> dict[str, Any]:
        """Put the twin into ``kind``'s state; ``ValueError`` for an unknown kind or
        arm, or one already active. Returns what the controller now shows."""
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {list(KINDS)}, got {kind!r}")
        arm = arm or next(iter(self.tasks))
        if arm not in self.tasks:
            raise ValueError(f"unknown arm {arm!r} (this twin has {list(self.tasks)})")
        with self._lock:
            if kind in self.active:
                raise ValueError(f"{kind} is already active")
            self.active[kind] = arm
        try:
            shown = getattr(self, f"_inject_{kind}")(arm)
        except Exception as exc:  # the controller refused (RwsError): nothing is active
            with self._lock:
                self.active.pop(kind, None)
            raise ValueError(f"injecting {kind}: {exc}") from None
        return {"kind": kind, "arm": arm, "shows": shown}

    def clear(self, kind: str) -> dict[str, Any]:
        """What a person does about ``kind`` (see the module doc); ``ValueError`` if it
        is not active. Returns the actions, in order."""
        with self._lock:
            if kind not in self.active:
                raise ValueError(f"{kind} is not active (active: {sorted(self.active)})")
            arm = self.active.pop(kind)
        try:
            actions: list[str] = getattr(self, f"_clear_{kind}")(arm)
        except Exception as exc:  # the controller refused (RwsError): still active
            with self._lock:
                self.active[kind] = arm
            raise ValueError(f"clearing {kind}: {exc}") from None
        return {"kind": kind, "arm": arm, "actions": actions}

    def state(self) -> dict[str, Any]:
        with self._lock:
            return {"active": dict(self.active)}

    # --- the controller's states --------------------------------------------------------
    def _inject_guard_stop(self, arm: str) -> str:
        self.controller.set_state(ctrlstate="guardstop")
        return "ctrlstate guardstop"

    def _clear_guard_stop(self, arm: str) -> list[str]:
        self.controller.set_state(ctrlstate="motoroff")
        self.controller.set_state(ctrlstate="motoron")
        return ["closed the guard (motoroff)", "pressed Motors On (motoron)"]

    def _inject_motors_off(self, arm: str) -> str:
        self.controller.set_state(ctrlstate="motoroff")
        return "ctrlstate motoroff"

    def _clear_motors_off(self, arm: str) -> list[str]:
        self.controller.set_state(ctrlstate="motoron")
        return ["pressed Motors On (motoron)"]

    def _inject_rapid_error(self, arm: str) -> str:
        code, title = RAPID_ERROR
        task = self.tasks[arm]
        self.controller.task_error(task, code, title,
                                   desc=f"Task {task}: a RAPID run-time error stopped "
                                        "the program.")
        return f"event log {code} {title!r} in {task}, execution stopped"

    def _clear_rapid_error(self, arm: str) -> list[str]:
        self.controller.resetpp()
        return ["PP to Main on the FlexPendant (program pointer reset)"]

    # --- the world zones ------------------------------------------------------------------
    def _inject_zone_stop(self, arm: str) -> str:
        task = self.tasks[arm]
        with self.cell_lock:
            x, y, z = self.cell.tcp_xyz()[arm]
        self.controller.task_error(
            task, WORLD_ZONE_CODE, WORLD_ZONE_TITLE,
            desc=f"Task {task}: the TCP of tool_pusher reached a stationary world zone at "
                 f"({x:g}, {y:g}, {z:g}) mm; every motion stopped.",
            actions="Move the arm out of the zone (above tb_zone_z), then PP to Main.",
            args=(task, "tb_wz_xlo", f"{x:g}", f"{y:g}", f"{z:g}"))
        return f"event log {WORLD_ZONE_CODE} {WORLD_ZONE_TITLE!r} in {task}, execution stopped"

    def _clear_zone_stop(self, arm: str) -> list[str]:
        actions = []
        top = self.zone_z.get(arm)
        with self.cell_lock:
            x, y, z = self.cell.tcp_xyz()[arm]
            if top is not None and z < top:
                self.cell.halt({arm: (x, y, top + JOG_ABOVE_MM)})
                self.publish()
                actions.append(f"jogged {arm} up to z {top + JOG_ABOVE_MM:g} mm")
            else:
                actions.append(f"no jog needed: {arm}'s TCP is at z {z:g} mm, above "
                               f"tb_zone_z")
        self.controller.resetpp()
        return [*actions, "PP to Main on the FlexPendant (program pointer reset)"]

    # --- the camera -----------------------------------------------------------------------
    def _inject_camera_frozen(self, arm: str) -> str:
        self.frames.freeze(True)
        return "the camera sends one picture over and over"

    def _clear_camera_frozen(self, arm: str) -> list[str]:
        self.frames.freeze(False)
        with self.cell_lock:
            self.publish()
        return ["restarted the camera (fresh frames)"]
