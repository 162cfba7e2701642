"""The host agent: ``python -m drivers.agent --backend NAME ...`` on the robot host.

Why a separate process speaking frames on stdin/stdout: the same program runs under an
SSH exec channel in the lab and under a local pipe in twin mode, so the controller has
one code path, and the robot host needs no open port and no daemon. stdout carries
ONLY frames: the agent duplicates fd 1 for its frames and points fd 1 (and
``sys.stdout``) at stderr before anything else is imported, because pybullet prints its
build time to fd 1 at import and a stray ``print`` would corrupt the stream.

Split by job: ``agent_cli.py`` (the flags: the common ones and the backend plugin's own,
the robot's lock, ``main``), ``agent_session.py`` (the reader and the one worker),
``agent_watchdog.py`` (the silence rule and the one way a backend is stopped),
``agent_dispatch.py`` (a request to the backend's call and its reply), ``agent_io.py``
(the two file descriptors).

Lifecycle::

    a backend with a controller (a YuMi): ask it who it is (serial, RobotWare; one
    read-only login)
    -> take the robot's lock (drivers.hostlock; a second agent for the same robot is
    refused and never builds its backend) -> start backend (errors kept for the hello
    reply) -> wait for hello (version check; hello_ok names this build, drivers.build_id,
    and a YuMi's controller as it named itself)
    -> serve observe / push / reset / rest / reseed / frame / move_tcp / save_calibration /
       describe
       in order, in ONE worker thread, while the reader answers heartbeat and stop at
       once, until bye, EOF, a broken frame, or no frame for --idle-timeout seconds
       while no request runs (the controller or the link is dead)
    -> bye: arms to rest (only after a request that may move one: observe, push,
       reset, rest, move_tcp), then bye_ok; anything else: NO motion
    -> finally: backend closed, lock released

Why a reader beside the worker (protocol 3): a push on a real arm is a motion of
seconds. While it runs the reader still hears the controller: heartbeats are answered
(the controller knows the agent lives), and ``stop`` reaches ``backend.stop()`` at once
instead of waiting behind the motion it should stop.

An orphaned agent never moves an arm: once its controller is gone (EOF, idle timeout,
broken pipe, broken frame) nobody is watching the cell, so it stops the motion in
progress (``backend.stop()``), runs none of the requests still queued, and closes the
backend where the arms are. Arms rest only when asked (``rest``, ``bye``; a session
that only looked, describe and frame, is not asked at bye either). With
``--watchdog S`` the same stop comes when a request runs and no frame at all has come
from the controller for S seconds: a v3 controller heartbeats during every call, so
silence means the link stopped answering.

A backend exception answers that one request with an ``error`` frame carrying the arm
and the traceback (a ``BackendError``, an expected refusal: its message alone); the
agent keeps serving. A broken frame (bad magic, length, CRC, truncation) cannot be
resynchronised: the agent answers ``error`` (fatal) and exits.
"""

from __future__ import annotations

from drivers.agent.agent_cli import BackendFactory, backend_kwargs, main, parse_args
from drivers.agent.agent_cli import _backend_kwargs as _backend_kwargs
from drivers.agent.agent_io import claim_stdout, fd_reader, fd_writer
from drivers.agent.agent_session import (
    EXIT_IDLE,
    EXIT_LINK,
    EXIT_OK,
    EXIT_PROTOCOL,
    EXIT_STARTUP,
    EXIT_USAGE,
    EXIT_VERSION,
    serve,
)

__all__ = ["EXIT_IDLE", "EXIT_LINK", "EXIT_OK", "EXIT_PROTOCOL", "EXIT_STARTUP", "EXIT_USAGE",
           "EXIT_VERSION", "BackendFactory", "backend_kwargs", "claim_stdout", "fd_reader",
           "fd_writer", "main", "parse_args", "serve"]
