"""Helpers for the tests that drive OUR RAPID on the twin through the UNCHANGED ABB RWS
client: the client with a timeout (it sets none), motion programs as the driver builds
them (``abb_motion_program_exec``'s bytes, a tool pointing down), and one run the way the
driver does it (each task's file uploaded, ``resetpp``, ``start(cycle="once")``, polled to
stopped) returning the event-log entries it wrote; a twin playing our RAPID on a real
cell (:func:`our_twin`), and the driver's "stay" program (one ``WaitTime 0``)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from abb_motion_program_exec import abb_motion_program_exec_client as mpe
from abb_robot_client.rws import RWS

from sim_twin.rws import Irc5Controller, RwsServer
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.rws_service import RwsService
from sim_twin.rws.testbed_file import V_TCP_MAX
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
from sim_twin.yumi_arms import DEFAULT_TOOL_MM
from sim_twin.yumi_cell import YumiTwinCell
from sim_twin.yumi_geometry import REST_JOINTS_DEG

DOWN = [0.0, 0.0, 1.0, 0.0]
Move = tuple[str, Any, float]
"""("J" | "L", (x, y, z) mm, v_tcp mm/s), or ("R", side, v_tcp): a joint move to that
side's rest joints (sim_twin.yumi_geometry.REST_JOINTS_DEG), as the driver rests an arm."""


def client(url: str, timeout_s: float = 20.0, **kw: Any) -> RWS:
    """The unchanged ABB client, with a timeout on its requests."""
    c = RWS(url, **kw)
    plain = c._session.request
    c._session.request = lambda m, u, **k: plain(m, u, **{"timeout": timeout_s, **k})  # type: ignore[method-assign]
    return c


ARM_ANGLE_DEG = {"left": 130.0, "right": -130.0}
"""The arm angle (axis 7) of the pushes (testbed/lab/camera_model.py PUSH_ARM_ANGLE_DEG)."""


def rt(x: float, y: float, z: float) -> Any:
    """A tool-down target; its arm angle the side's (left: y > 0). Our RAPID moves with
    ConfJ off, so the confdata is not kept."""
    angle = ARM_ANGLE_DEG["left" if y >= 0 else "right"]
    return mpe.robtarget([x, y, z], DOWN, mpe.confdata(0, 0, 0, 4), [angle] + [9e9] * 5)


def tool(tool_z_mm: float = DEFAULT_TOOL_MM, rot: Sequence[float] = (1, 0, 0, 0),
         trans_xy: Sequence[float] = (0, 0), robhold: bool = True) -> Any:
    """The tooldata a program file carries (the calibration's tool_z_mm; its load is not
    used: the controller's tool_pusher holds the real one)."""
    return mpe.tooldata(robhold, mpe.pose([*trans_xy, tool_z_mm], list(rot)),
                        mpe.loaddata(0.1, [0, 0, 50], [1, 0, 0, 0], 0, 0, 0))


def program(moves: Sequence[Move], tool_z_mm: float = DEFAULT_TOOL_MM, wobj: Any = None,
            tooldata: Any = None) -> Any:
    """A program of MoveJ/MoveL stop points with a tool ``tool_z_mm`` long (default: the
    twin's own, so a target is where the pusher's tip goes), or ``tooldata``."""
    tool_ = tooldata if tooldata is not None else tool(tool_z_mm)
    mp = mpe.MotionProgram(tool=tool_, wobj=wobj) if wobj is not None else \
        mpe.MotionProgram(tool=tool_)
    for kind, xyz, v in moves:
        speed = mpe.speeddata(min(v, V_TCP_MAX), 100, 1000, 100)  # within our RAPID's caps
        if kind == "R":
            j = REST_JOINTS_DEG[xyz]
            mp.MoveAbsJ(mpe.jointtarget(list(j[:6]), [j[6]] + [9e9] * 5), speed, mpe.fine)
        else:
            (mp.MoveJ if kind == "J" else mp.MoveL)(rt(*xyz), speed, mpe.fine)
    return mp


def newest(c: RWS) -> int | None:
    log = c.read_event_log()
    return log[0].seqnum if log else None


def since(c: RWS, prev: int | None) -> list[Any]:
    """The event-log entries after ``prev``, oldest first."""
    return [e for e in reversed(c.read_event_log()) if prev is None or e.seqnum > prev]


def start(c: RWS, programs: Mapping[str, Any], seqno: int = 1) -> int | None:
    """Upload each task's program to the file our RAPID reads and start those tasks;
    returns the newest event-log entry before the start."""
    prev = newest(c)
    for task, mp in programs.items():
        c.upload_file(f"$TEMP/testbed_{task}.bin", mp.get_program_bytes(seqno=seqno))
    c.resetpp()
    c.start(cycle="once", tasks=list(programs))
    return prev


def wait_stopped(c: RWS, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while c.get_execution_state().ctrlexecstate == "running":
        assert time.monotonic() < deadline, "RAPID still running"
        time.sleep(0.01)


def run(c: RWS, programs: Mapping[str, Any], seqno: int = 1) -> list[Any]:
    """One run to its end; the entries it wrote (oldest first, ``resetpp``'s left out)."""
    prev = start(c, programs, seqno)
    wait_stopped(c)
    return [e for e in since(c, prev) if e.code != 10002]


def stay(tool_z_mm: float = DEFAULT_TOOL_MM) -> Any:
    """The driver's program for an arm with nothing to do: one ``WaitTime 0`` (op 5), with
    the calibration's tool frame like every program."""
    mp = mpe.MotionProgram(tool=tool(tool_z_mm))
    mp.WaitTime(0)
    return mp


@dataclass
class OurTwin:
    """Our RAPID installed on a twin controller over a real cell, served over HTTP."""

    c: RWS
    ctrl: Irc5Controller
    install: TestbedInstall
    hook: TestbedRapid
    cell: YumiTwinCell
    lock: threading.Lock

    def tcps(self) -> dict[str, tuple[float, float, float]]:
        """The pushers' tips (the cell's truth), world frame, mm."""
        with self.lock:
            return self.cell.tcp_xyz()


@contextmanager
def our_twin(*, omit_motiontask: bool = False, **hook_kw: Any) -> Iterator[OurTwin]:
    """An :class:`OurTwin` (``hook_kw`` to :class:`TestbedRapid`), stopped afterwards."""
    cell = YumiTwinCell(3)
    lock = threading.Lock()
    hook = TestbedRapid(cell, lock, YUMI_UNITS, **hook_kw)
    ctrl = Irc5Controller(units=YUMI_UNITS, poses=hook.poses, omit_motiontask=omit_motiontask)
    install = TestbedInstall(ctrl, hook)
    server = RwsServer(RwsService(ctrl, program=install)).start_thread()
    try:
        yield OurTwin(client(server.url), ctrl, install, hook, cell, lock)
    finally:
        server.stop()
        cell.close()
