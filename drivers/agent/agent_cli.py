"""The agent's command line: its flags (the common ones and its backend's), its lock, main.

Why apart from the session: what an agent serves is decided here, once, before the first
frame: which backend (``--backend``, any installed plugin: ``testbed.core.backend_registry``),
with which flags (the plugin adds and reads its own: ``BackendPlugin.add_agent_arguments``
and ``backend_kwargs``, the same object that wrote them on the controller), and which
robot it must own exclusively (``--lock-id``, or what the plugin says of its robot). The
agent itself never names a robot.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from drivers import wire as p
from drivers.agent.agent_io import claim_stdout, fd_reader, fd_writer
from drivers.agent.agent_session import EXIT_USAGE, serve
from drivers.build_id import build_id
from drivers.hostlock import RobotLock, default_lock_dir
from testbed.core.backend_registry import BackendError

if TYPE_CHECKING:
    from drivers.backends.base import HostBackend

__all__ = ["BackendFactory", "backend_kwargs", "main", "parse_args"]

log = logging.getLogger("drivers.agent")


def _common_parser(names: Sequence[str]) -> argparse.ArgumentParser:
    """The flags every agent has, whatever its robot; ``names``: the installed backends."""
    ap = argparse.ArgumentParser(prog="python -m drivers.agent",
                                 description="Serve one robot host's arms on stdin/stdout.")
    ap.add_argument("--backend", choices=sorted(names), required=True,
                    help="the robot this host has (any installed backend plugin)")
    ap.add_argument("--host", default="host", help="host name, for messages")
    ap.add_argument("--arms", default="left,right")
    ap.add_argument("--mirror", default=None, help="0/1 per arm (default: right arms mirror)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--calibrate", action="append", default=[], metavar="ARM",
                    help="this arm is being calibrated (provisional calibration; frame, "
                         "move_tcp, rest and save_calibration only); repeatable")
    ap.add_argument("--lock-dir", default=None,
                    help="directory of the per-robot lock files, shared by every user of "
                         "the host (default /run/lock/fleet-testbed)")
    ap.add_argument("--lock-id", default=None,
                    help="lock this identity (default: what the backend says of its robot, "
                         "e.g. a YuMi's controller serial; a twin: no lock, every twin "
                         "agent owns its own cell)")
    ap.add_argument("--idle-timeout", type=float, default=120.0,
                    help="exit (arms NOT moved) after this long without a frame")
    ap.add_argument("--watchdog", type=float, default=None, metavar="S",
                    help="while a request runs, stop the motion if no frame at all came "
                         "from the controller for S seconds (the controller heartbeats "
                         "during motions; default: no watchdog)")
    ap.add_argument("--chdir", default=None, help="working directory (the project checkout)")
    return ap


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The common flags, then the chosen backend's own (its plugin adds them), so
    ``--help`` after ``--backend NAME`` shows them and an unknown flag is an error.

    Two phases: ``--backend`` alone first, by a parser without ``--help`` (a full parser
    would print its help, without the backend's flags, and exit before they are added),
    then every flag. A broken plugin raises ``BackendError`` (:func:`main`: one line)."""
    from drivers.backends.plugin import agent_plugins

    plugins = agent_plugins()
    first = argparse.ArgumentParser(add_help=False)
    first.add_argument("--backend", default=None)
    chosen = plugins.get(first.parse_known_args(argv)[0].backend)
    ap = _common_parser(plugins)
    if chosen is not None:
        chosen.add_agent_arguments(ap.add_argument_group(f"{chosen.name} backend"))
    args = ap.parse_args(argv)  # an unknown or missing backend: a usage error, exit 2
    args.plugin = plugins[args.backend]
    return args


BackendFactory = Callable[[argparse.Namespace, dict[str, Any]], "HostBackend"]
"""``(args, kwargs) -> backend``: how :func:`main` builds its backend from the parsed
argv and the keyword arguments of the plugin's ``make_backend`` it derived."""


def backend_kwargs(args: argparse.Namespace) -> dict[str, Any] | str:
    """The plugin's ``make_backend`` keyword arguments from the argv (the common ones,
    then the backend's own), or one line saying what is wrong with it."""
    arms = [a for a in args.arms.split(",") if a]
    if args.mirror is None:
        mirror = [a.startswith("right") for a in arms]
    else:
        mirror = [m.strip() in ("1", "true") for m in args.mirror.split(",")]
    if len(mirror) != len(arms):
        return f"--mirror needs one value per arm ({len(arms)})"
    own = args.plugin.backend_kwargs(args)
    if isinstance(own, str):
        return own
    return {"arms": arms, "mirror": mirror, "seed": args.seed,
            "calibrating": list(args.calibrate), **own}


_backend_kwargs = backend_kwargs  # the name the drivers' tests have used


def _make_backend(args: argparse.Namespace, kwargs: dict[str, Any]) -> HostBackend:
    """The plugin's backend, imported only now (pybullet prints; a robot's clients)."""
    return args.plugin.make_backend(**kwargs)


def _robot_identity(args: argparse.Namespace, controller: Mapping[str, str] | None
                    ) -> str | None:
    """What this agent must own exclusively: ``--lock-id``, else what a backend with the
    ``robot_lock`` capability says of its robot; None: it owns what it drives."""
    if args.lock_id:
        return str(args.lock_id)
    if not args.plugin.capabilities.robot_lock:
        return None
    return args.plugin.robot_identity(args, controller)


def main(argv: Sequence[str] | None = None, *,
         backend_factory: BackendFactory | None = None) -> int:
    """The agent process. ``backend_factory``: the tests' seam (their own backend, e.g.
    an arm that moves for seconds, behind the real agent: ``tests/drivers/slow_arm.py``);
    the command line never reaches it."""
    frames_fd = claim_stdout()
    try:
        args = parse_args(argv)
    except BackendError as exc:  # a broken plugin on this host: one line, not a traceback
        print(f"python -m drivers.agent: {exc}", file=sys.stderr)
        return EXIT_USAGE
    logging.basicConfig(stream=sys.stderr, level=logging.WARNING,
                        format=f"%(asctime)s agent[{args.host}] %(levelname)s %(message)s")
    log.setLevel(logging.INFO)  # our lifecycle lines (a few per session), not others
    if args.chdir:
        os.chdir(args.chdir)
    kwargs = backend_kwargs(args)
    if isinstance(kwargs, str):
        print(kwargs, file=sys.stderr)
        return EXIT_USAGE
    build = backend_factory or _make_backend
    log.info("agent pid %d for host %s: backend %s, protocol %d, build %s", os.getpid(),
             args.host, args.backend, p.PROTOCOL_VERSION, build_id())
    held: list[RobotLock] = []
    hello_fields: dict[str, Any] = {}

    def factory() -> HostBackend:
        controller = (args.plugin.controller_info(args)
                      if args.plugin.capabilities.controller else None)
        if controller is not None:
            hello_fields["controller"] = controller
        identity = _robot_identity(args, controller)
        if identity is not None:  # before anything moves the robot (refusal: at hello)
            lock = RobotLock(identity, args.lock_dir or default_lock_dir(), args.host,
                             controller=args.plugin.controller_address(args))
            lock.acquire()
            held.append(lock)
            log.info("holding the lock of robot %s (%s)", lock.identity, lock.path)
        return build(args, kwargs)

    reader = p.FrameReader(fd_reader(0), "controller")
    try:
        return serve(reader, fd_writer(frames_fd, max(10.0, args.idle_timeout)), factory,
                     idle_timeout_s=args.idle_timeout, watchdog_s=args.watchdog,
                     hello_fields=hello_fields)
    finally:
        for lock in held:
            lock.release()
        for fd in (0, frames_fd):  # leave a terminal as we found it
            with contextlib.suppress(OSError):
                os.set_blocking(fd, True)
