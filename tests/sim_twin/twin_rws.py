"""Helpers for the tests that drive OUR RAPID on the twin through the UNCHANGED ABB RWS
client: the client with a timeout (it sets none), motion programs as the driver builds
them (``abb_motion_program_exec``'s bytes, a tool pointing down), and one run the way the
driver does it (each task's file uploaded, ``resetpp``, ``start(cycle="once")``, polled to
stopped) returning the event-log entries it wrote."""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import Any

from abb_motion_program_exec import abb_motion_program_exec_client as mpe
from abb_robot_client.rws import RWS

from sim_twin.yumi_arms import DEFAULT_TOOL_MM
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


def program(moves: Sequence[Move], tool_z_mm: float = DEFAULT_TOOL_MM, wobj: Any = None
            ) -> Any:
    """A program of MoveJ/MoveL stop points with a tool ``tool_z_mm`` long (default: the
    twin's own, so a target is where the pusher's tip goes)."""
    tool = mpe.tooldata(True, mpe.pose([0, 0, tool_z_mm], [1, 0, 0, 0]),
                        mpe.loaddata(0.1, [0, 0, 50], [1, 0, 0, 0], 0, 0, 0))
    mp = mpe.MotionProgram(tool=tool, wobj=wobj) if wobj is not None else \
        mpe.MotionProgram(tool=tool)
    for kind, xyz, v in moves:
        speed = mpe.speeddata(v, 500, 5000, 1000)
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
