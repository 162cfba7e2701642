"""``python -m sim_twin.rws``: an RWS 1.0 twin of the YuMi's IRC5 as a process.

Why a process: the agent's controller seam reaches the controller over the network; a
rehearsal (later) starts one of these per YuMi host, as it starts a hardware twin.

Usage::

    python -m sim_twin.rws [--host 127.0.0.1] [--port 0] [--port-file F]
        [--max-sessions 70] [--user NAME:PASSWORD ...] [--grants NAME=GRANTS ...]
        [--idle-timeout S]
        [--ramdisk-value '$TEMP'] [--opmode AUTO] [--ctrlstate motoron]
        [--cell --arms left,right --seed S --pusher-length-mm L --realtime R
         --rapid testbed|library] [--omit-motiontask] [--verbose]

``Default User`` / ``robotics`` always log in; ``--user`` adds more. Their UAS grants
(``sim_twin.rws.uas``): ``Default User`` every grant, an added user none (fail closed)
unless ``--grants NAME=agent|person|factory|none|UAS_ID,...`` gives them (``agent``:
robot/README.md's four; a bad one: exit 2). With ``--cell`` the
arms' positions come from a ``YumiTwinCell`` (PyBullet) made here and a RAPID start runs
the uploaded motion programs on it (``--realtime`` paces the motion, 0: as fast as
computed) with the semantics of ``--rapid``: ``testbed`` (the default) our RAPID
(``testbed_rapid.TestbedRapid``: one file per task, its symbols and its world zones at
the defaults of ``world_zones.default_zone``), ``library`` the library's
(``motion_exec.CellMotion``); without ``--cell``, the positions are fixed and a start
ends at once. (``sim_twin.yumi_server`` serves the same RWS beside the hardware twin's
camera, with zones and a request log.) It writes the port (a decimal line) to
``--port-file`` once listening, serves until SIGTERM/SIGINT and exits 0 (2 on a bad argument).
``--omit-motiontask``: ``GET rw/rapid/tasks`` without the ``motiontask`` field
(``Irc5Controller.omit_motiontask``: a controller as in abb_motion_program_exec issue 4).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sim_twin.port_file import write_port
from sim_twin.rws.digest_auth import DEFAULT_USERS
from sim_twin.rws.file_store import DEFAULT_RAMDISK_VALUE, FileStore
from sim_twin.rws.irc5 import CTRLSTATES, OPMODES, Irc5Controller, StartHook
from sim_twin.rws.mechunits import YUMI_UNITS, MechUnit, PoseSource
from sim_twin.rws.rws_server import RwsServer, check_loopback
from sim_twin.rws.rws_service import LabProgram, RwsService
from sim_twin.rws.uas import grants_of_users, parse_grants


def _args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m sim_twin.rws",
                                description="An RWS 1.0 (RobotWare 6) twin of the YuMi's IRC5.")
    p.add_argument("--host", default="127.0.0.1", help="a loopback address")
    p.add_argument("--port", type=int, default=0, help="0: any free port")
    p.add_argument("--port-file", type=Path, default=None)
    p.add_argument("--max-sessions", type=int, default=70)
    p.add_argument("--user", action="append", default=[], metavar="NAME:PASSWORD")
    p.add_argument("--grants", action="append", default=[], metavar="NAME=GRANTS",
                   help="a user's UAS grants: a role (agent, person, factory, none) or "
                        "UAS_... ids separated by commas")
    p.add_argument("--idle-timeout", type=float, default=None, metavar="S",
                   help="drop sessions idle this long (default: never)")
    p.add_argument("--ramdisk-value", default=DEFAULT_RAMDISK_VALUE,
                   help="what ctrl/$RAMDISK answers")
    p.add_argument("--opmode", default="AUTO", choices=OPMODES)
    p.add_argument("--ctrlstate", default="motoron", choices=CTRLSTATES)
    p.add_argument("--cell", action="store_true", help="positions from a YumiTwinCell")
    p.add_argument("--arms", default="left,right")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--pusher-length-mm", type=float, default=0.0,
                   help="flange above the cell's TCP (tool0 = flange)")
    p.add_argument("--realtime", type=float, default=0.0,
                   help="with --cell: motion paced at this multiple of real time (0: unpaced)")
    p.add_argument("--rapid", default="testbed", choices=("testbed", "library"),
                   help="with --cell: whose RAPID a start plays (ours, or the library's)")
    p.add_argument("--omit-motiontask", action="store_true",
                   help="GET rw/rapid/tasks leaves the motiontask field out")
    p.add_argument("--verbose", action="store_true")
    a = p.parse_args(argv)
    try:
        check_loopback(a.host)
    except ValueError as exc:
        p.error(str(exc))
    if a.max_sessions < 1:
        p.error("--max-sessions must be >= 1")
    for u in a.user:
        if ":" not in u or not u.split(":", 1)[0]:
            p.error(f"--user {u!r}: expected NAME:PASSWORD")
    try:
        a.user_grants = grants_of_users(_users(a), dict(_grant_arg(g) for g in a.grants))
    except ValueError as exc:
        p.error(f"--grants: {exc}")
    return a


def _users(a: argparse.Namespace) -> dict[str, str]:
    users = dict(DEFAULT_USERS)
    users.update({name: pw for name, _, pw in (u.partition(":") for u in a.user)})
    return users


def _grant_arg(text: str) -> tuple[str, frozenset[str]]:
    """``NAME=GRANTS`` (the last ``=`` separates them: a user's name may hold one)."""
    name, eq, spec = text.rpartition("=")
    if not eq or not name:
        raise ValueError(f"{text!r}: expected NAME=GRANTS")
    return name, parse_grants(spec)


def _cell_hook(a: argparse.Namespace, units: tuple[MechUnit, ...]
               ) -> tuple[Any, PoseSource, StartHook]:
    """A cell for ``--arms`` and the start hook of ``--rapid`` on it."""
    from sim_twin.rws.motion_exec import CellMotion
    from sim_twin.rws.testbed_rapid import TestbedRapid
    from sim_twin.yumi_cell import YumiTwinCell  # PyBullet: only when asked for

    cell = YumiTwinCell(a.seed, tuple(u.arm for u in units), realtime=a.realtime)
    kind = TestbedRapid if a.rapid == "testbed" else CellMotion
    motion = kind(cell, threading.Lock(), units, pusher_length_mm=a.pusher_length_mm)
    return cell, motion.poses, motion


def main(argv: Sequence[str] | None = None) -> int:
    a = _args(argv)
    arms = tuple(s.strip() for s in a.arms.split(",") if s.strip())
    units = tuple(u for u in YUMI_UNITS if u.arm in arms)
    if not units:
        print(f"sim_twin.rws: no YuMi arm in --arms {a.arms!r} (left, right)", file=sys.stderr)
        return 2
    cell: Any = None
    poses: PoseSource | None = None
    hook: StartHook | None = None
    if a.cell:
        cell, poses, hook = _cell_hook(a, units)
    users = _users(a)
    controller = Irc5Controller(units=units, poses=poses, on_start=hook, opmode=a.opmode,
                                ctrlstate=a.ctrlstate, files=FileStore(
                                    ramdisk_value=a.ramdisk_value),
                                omit_motiontask=a.omit_motiontask)
    program: LabProgram | None = None
    if a.cell and a.rapid == "testbed":
        from sim_twin.rws.testbed_install import TestbedInstall
        from sim_twin.rws.testbed_rapid import TestbedRapid

        assert isinstance(hook, TestbedRapid)
        program = TestbedInstall(controller, hook)  # our modules' symbols, the lab's switch
    service = RwsService(controller, users=users, max_sessions=a.max_sessions,
                         idle_timeout_s=a.idle_timeout, program=program,
                         grants=a.user_grants)
    server = RwsServer(service, a.host, a.port, verbose=a.verbose)
    done = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        done.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    server.start_thread()
    if a.port_file is not None:
        write_port(a.port_file, server.port)
    print(f"sim_twin.rws: {','.join(u.name for u in units)} on {server.url} "
          f"(max {a.max_sessions} sessions)", file=sys.stderr, flush=True)
    try:
        while not done.wait(0.5):
            pass
    finally:
        server.stop()
        if cell is not None:
            cell.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
