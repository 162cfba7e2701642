"""Helpers for the tests that drive OUR RAPID on the twin through the UNCHANGED ABB RWS
client: the client with a timeout (it sets none), motion programs as the driver builds
them (``abb_motion_program_exec``'s bytes, a tool pointing down), and one run the way the
driver does it (each task's file uploaded, ``resetpp``, ``start(cycle="once")``, polled to
stopped) returning the event-log entries it wrote; a twin playing our RAPID on a real
cell (:func:`our_twin`), and the driver's "stay" program (one ``WaitTime 0``). The twin's
logins: the factory ``Default User`` (every grant) and :data:`PERSON`, a user with the
person's UAS grants (robot/README.md; ``sim_twin.rws.uas.PERSON_GRANTS``): a test that
writes RAPID data or restarts the controller does it as the person (:func:`as_person`)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
from abb_motion_program_exec import abb_motion_program_exec_client as mpe
from abb_robot_client.rws import RWS
from arm_plan import plan_nearest

from sim_twin.rws import Irc5Controller, RwsServer
from sim_twin.rws.digest_auth import DEFAULT_USERS
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.rws_service import RwsService
from sim_twin.rws.testbed_file import V_TCP_MAX
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
from sim_twin.rws.uas import PERSON_GRANTS
from sim_twin.sew_angle import arm_angle
from sim_twin.yumi_arms import DEFAULT_TOOL_MM, ArmModel, abb_to_chain
from sim_twin.yumi_cell import YumiTwinCell
from sim_twin.yumi_geometry import REST_JOINTS_DEG

DOWN = [0.0, 0.0, 1.0, 0.0]
Move = tuple[Any, ...]
"""("J" | "L", (x, y, z) mm, v_tcp mm/s[, arm angle]), or ("R", side, v_tcp): a joint
move to that side's rest joints (sim_twin.yumi_geometry.REST_JOINTS_DEG), as the driver
rests an arm. The arm angle (deg) where a test needs its own (e.g.
:data:`UNDER_SHOULDER_DEG`); else the driver's plan's (:func:`arm_angles`)."""
UNDER_SHOULDER_DEG = {"left": -30.0, "right": 30.0}
"""An arm angle at which the pusher, down, goes up and down over the table with axis 2
below 0 all the way (about -25 to -45; axis 7 from about +-50 at 120 mm to +-115 near
the table, not +-130): for a test whose line goes down through about 60 mm. Why: there
the driver's plan (axis 7 at +-130) passes axis 2 = 0, where axes 1 and 7 line up (the
shoulder's singularity), and turns the arm angle across it, which the controller cannot
follow (50026, or axis 1 past its limit: the twin's
``sim_twin/rws/arm_supervision.py``); one arm angle under the shoulder never meets it."""


def client(url: str, timeout_s: float = 20.0, **kw: Any) -> RWS:
    """The unchanged ABB client, with a timeout on its requests."""
    c = RWS(url, **kw)
    plain = c._session.request
    c._session.request = lambda m, u, **k: plain(m, u, **{"timeout": timeout_s, **k})  # type: ignore[method-assign]
    return c


PERSON = ("person", "installs-and-measures")
"""The person's login (install grants: load, edit, current value, restart, ...)."""
LOGINS: dict[str, Any] = {"users": {**DEFAULT_USERS, PERSON[0]: PERSON[1]},
                          "grants": {PERSON[0]: PERSON_GRANTS}}
"""``RwsService(..., **LOGINS)``: the factory login and :data:`PERSON`."""


def as_person(url: str) -> RWS:
    """The ABB client logged in as :data:`PERSON`."""
    return client(url, username=PERSON[0], password=PERSON[1])


def rt(x: float, y: float, z: float, angle: float) -> Any:
    """A tool-down target with the arm angle ``angle`` (``eax_a``: ABB's arm angle, not
    axis 7's value; docs/notes/rws.md, "What eax_a means on a YuMi"). Our RAPID moves
    with ConfJ off, so the confdata is not kept."""
    return mpe.robtarget([x, y, z], DOWN, mpe.confdata(0, 0, 0, 4), [angle] + [9e9] * 5)


def _rotate(q: Sequence[float], v: Sequence[float]) -> list[float]:
    """``v`` turned by the unit quaternion ``q`` (w, x, y, z)."""
    w, u = float(q[0]), np.asarray(q[1:], dtype=np.float64)
    p = np.asarray(v, dtype=np.float64)
    return list(p + 2.0 * np.cross(u, np.cross(u, p) + w * p))


def in_base(xyz: Sequence[float], wobj: Any) -> list[float]:
    """A point of the work object ``wobj`` (None: wobj0) in the robot's base frame:
    uframe, then oframe."""
    if wobj is None:
        return [float(v) for v in xyz]
    p = list(xyz)
    for frame in (wobj.oframe, wobj.uframe):
        p = [a + b for a, b in zip(_rotate(frame.rot, p), frame.trans, strict=True)]
    return p


def arm_angles(moves: Sequence[Move], tool_z_mm: float, wobj: Any = None) -> list[float]:
    """The arm angle of each MoveJ/MoveL of ``moves`` (0 for an "R"): the move's own where
    it names one, else the one of the joints the driver plans for it, axis 7 at the
    push's +-130 (``arm_plan.plan_nearest``), each from
    the joints planned before it on that side (from rest at first and after an "R"), as
    the driver chains a program's targets. The pushes were planned so, and a robtarget's
    ``eax_a`` is that configuration's arm angle, not 130. A target the driver's model
    cannot reach keeps the arm angle of the joints before it: the twin answers it with
    its own code (50050, 50027)."""
    current: dict[str, list[float]] = {}
    out: list[float] = []
    for kind, xyz, _, *named in moves:
        if kind == "R":
            current.pop(xyz, None)
            out.append(0.0)
            continue
        side = "left" if xyz[1] >= 0 else "right"
        start = current.get(side, abb_to_chain(REST_JOINTS_DEG[side]))
        got = plan_nearest(side, in_base(xyz, wobj), start, tool_z_mm)
        if got is not None:
            current[side] = got[0]
        if named:
            out.append(float(named[0]))
        else:
            out.append(arm_angle(ArmModel(side).pose(start)) if got is None else got[1])
    return out


def tool(tool_z_mm: float = DEFAULT_TOOL_MM, rot: Sequence[float] = (1, 0, 0, 0),
         trans_xy: Sequence[float] = (0, 0), robhold: bool = True) -> Any:
    """The tooldata a program file carries (the calibration's tool_z_mm; its load is not
    used: the controller's tool_pusher holds the real one)."""
    return mpe.tooldata(robhold, mpe.pose([*trans_xy, tool_z_mm], list(rot)),
                        mpe.loaddata(0.1, [0, 0, 50], [1, 0, 0, 0], 0, 0, 0))


def program(moves: Sequence[Move], tool_z_mm: float = DEFAULT_TOOL_MM, wobj: Any = None,
            tooldata: Any = None) -> Any:
    """A program of MoveJ/MoveL stop points with a tool ``tool_z_mm`` long (default: the
    twin's own, so a target is where the pusher's tip goes), or ``tooldata``; each
    robtarget with the arm angle of the joints the driver plans for it (:func:`arm_angles`).
    Speeds as
    the driver writes them: ``v_tcp`` the move's, at most the shipped cap
    ``tb_v_tcp_max`` (150: a faster one is sent at the cap, as a calibration's
    max_speed_mm_s above it is the lab's error), v_ori 100, v_leax 1000, v_reax 100; the
    refusals past the caps are tests/sim_twin/test_rws_hostile_files.py's."""
    tool_ = tooldata if tooldata is not None else tool(tool_z_mm)
    mp = mpe.MotionProgram(tool=tool_, wobj=wobj) if wobj is not None else \
        mpe.MotionProgram(tool=tool_)
    angles = arm_angles(moves, float(tool_.tframe.trans[2]), wobj)
    for (kind, xyz, v, *_), angle in zip(moves, angles, strict=True):
        speed = mpe.speeddata(min(v, V_TCP_MAX), 100, 1000, 100)
        if kind == "R":
            j = REST_JOINTS_DEG[xyz]
            mp.MoveAbsJ(mpe.jointtarget(list(j[:6]), [j[6]] + [9e9] * 5), speed, mpe.fine)
        else:
            (mp.MoveJ if kind == "J" else mp.MoveL)(rt(*xyz, angle), speed, mpe.fine)
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
    person: RWS
    """The same controller as :data:`PERSON` (RAPID data, restarts)."""

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
    server = RwsServer(RwsService(ctrl, program=install, **LOGINS)).start_thread()
    try:
        yield OurTwin(client(server.url), ctrl, install, hook, cell, lock,
                      as_person(server.url))
    finally:
        server.stop()
        cell.close()
