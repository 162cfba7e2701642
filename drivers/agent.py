"""The host agent: ``python -m drivers.agent --backend twin|yumi ...`` on the robot host.

Why a separate process speaking frames on stdin/stdout: the same program runs under an
SSH exec channel in the lab and under a local pipe in twin mode, so the controller has
one code path, and the robot host needs no open port and no daemon. stdout carries
ONLY frames: the agent duplicates fd 1 for its frames and points fd 1 (and
``sys.stdout``) at stderr before anything else is imported, because pybullet prints its
build time to fd 1 at import and a stray ``print`` would corrupt the stream.

Lifecycle::

    a YuMi: ask its controller who it is (serial, RobotWare; one read-only login)
    -> take the robot's lock (drivers.hostlock; a second agent for the same robot is
    refused and never builds its backend) -> start backend (errors kept for the hello
    reply) -> wait for hello (version check; hello_ok names this build, drivers.build_id,
    and a YuMi's controller as it named itself)
    -> serve observe / push / reset / rest / reseed / frame / move_tcp / save_calibration /
       describe
       in order, in ONE worker thread, while the reader answers heartbeat and stop at
       once, until bye, EOF, a broken frame, or no frame for --idle-timeout seconds
       while no request runs (the controller or the link is dead)
    -> bye: arms to rest, then bye_ok; anything else: NO motion
    -> finally: backend closed, lock released

Why a reader beside the worker (protocol 3): a push on a real arm is a motion of
seconds. While it runs the reader still hears the controller: heartbeats are answered
(the controller knows the agent lives), and ``stop`` reaches ``backend.stop()`` at once
instead of waiting behind the motion it should stop.

An orphaned agent never moves an arm: once its controller is gone (EOF, idle timeout,
broken pipe, broken frame) nobody is watching the cell, so it stops the motion in
progress (``backend.stop()``), runs none of the requests still queued, and closes the
backend where the arms are. Arms rest only when asked (``rest``, ``bye``). With
``--watchdog S`` the same stop comes when a request runs and no frame at all has come
from the controller for S seconds: a v3 controller heartbeats during every call, so
silence means the link stopped answering.

A backend exception answers that one request with an ``error`` frame carrying the arm
and the traceback (a ``BackendError``, an expected refusal: its message alone); the
agent keeps serving. A broken frame (bad magic, length, CRC, truncation) cannot be
resynchronised: the agent answers ``error`` (fatal) and exits.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import queue
import select
import sys
import threading
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

# Light imports only (numpy, json, zlib): nothing here prints to fd 1. The backends
# (pybullet!) are imported in main(), after claim_stdout().
from drivers import wire as p
from drivers.backends.base import ArmView
from drivers.build_id import build_id
from drivers.errors import BackendError, DeadlineExceeded, LinkClosed, ProtocolError
from drivers.hostlock import RobotBusy, RobotLock, default_lock_dir, lock_identity

if TYPE_CHECKING:
    from drivers.backends.base import HostBackend

EXIT_OK = 0
EXIT_USAGE = 2
EXIT_PROTOCOL = 3
EXIT_VERSION = 4
EXIT_STARTUP = 5
EXIT_IDLE = 6
EXIT_LINK = 7

log = logging.getLogger("drivers.agent")


def claim_stdout() -> int:
    """Keep fd 1 for frames (returned dup) and send everything else printed to stderr."""
    frames_fd = os.dup(1)
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    return frames_fd


def fd_reader(fd: int) -> Callable[[int, float], bytes]:
    os.set_blocking(fd, False)

    def read(n: int, deadline: float) -> bytes:
        while True:
            try:
                return os.read(fd, n)  # a pipelined request is often there already
            except BlockingIOError:
                pass
            timeout = deadline - time.monotonic()
            if timeout <= 0:
                raise DeadlineExceeded("no frame from the controller in time")
            select.select([fd], [], [], timeout)

    return read


def fd_writer(fd: int, timeout_s: float) -> Callable[[bytes], None]:
    os.set_blocking(fd, False)

    def write(data: bytes) -> None:
        view = memoryview(data)
        deadline = time.monotonic() + timeout_s
        while view:
            try:
                n = os.write(fd, view)
            except BlockingIOError:
                n = 0
            view = view[n:]
            if view:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise BrokenPipeError("the controller stopped reading our replies")
                select.select([], [fd], [], left)

    return write


POLL_S = 0.05
"""While a request runs, the reader waits for frames in slices this long, so it notices
at once the worker ending the session (bye, a broken link) and the watchdog's silence."""
STOP_LIMIT_S = 0.5
"""``HostBackend.stop`` returns within this (the reader hears nothing meanwhile)."""
DRAIN_S = 10.0
"""At exit, how long the backend may take to return from a stopped request before it is
closed anyway."""


def serve(reader: p.FrameReader, write: Callable[[bytes], None],
          make_backend: Callable[[], HostBackend], *, idle_timeout_s: float = 120.0,
          watchdog_s: float | None = None,
          hello_fields: Mapping[str, Any] | None = None) -> int:
    """Serve one controller until bye/EOF/broken frame; returns the exit status.

    ``watchdog_s``: while a request runs, stop the backend once if no frame at all came
    from the controller for this long (None: no watchdog). ``hello_fields``: optional
    fields of ``hello_ok`` (``controller``: what the robot's controller said of itself),
    read at each hello, so ``make_backend`` may fill them. Never raises: every failure
    becomes an ``error`` frame and/or an exit status.
    """
    started = time.monotonic()
    backend: HostBackend | None = None
    startup_error: tuple[str, str] | None = None
    try:
        backend = make_backend()
    except Exception as exc:  # reported to the controller at hello
        what = str(exc) if isinstance(exc, RobotBusy) else f"{type(exc).__name__}: {exc}"
        startup_error = (what, traceback.format_exc())
        log.error("backend failed to start: %s", startup_error[0])
    session = _Session(reader, write, backend, startup_error, started,
                       idle_timeout_s=idle_timeout_s, watchdog_s=watchdog_s,
                       hello_fields=hello_fields or {})
    try:
        return session.run()
    finally:
        session.finish()


class _Session:
    """One controller's session: a reader (the calling thread) and one worker thread.

    Why two threads: a push is a motion of seconds on a real arm, and while it runs the
    controller must still be heard. The reader reads frames all the time and answers
    ``heartbeat`` and ``stop`` at once (stop: ``backend.stop()``, then ``stop_ok``);
    every other request goes, in order, to the ONE worker, so requests stay serial and
    in the order the controller pipelined them. Replies are written under one lock, so
    frames never interleave. The reader also keeps the watchdog and the idle timeout,
    and when the controller is gone (EOF, a broken frame, a broken pipe) it stops the
    motion in progress first, then the session ends without moving the arms.
    """

    def __init__(self, reader: p.FrameReader, write: Callable[[bytes], None],
                 backend: HostBackend | None, startup_error: tuple[str, str] | None,
                 started: float, *, idle_timeout_s: float, watchdog_s: float | None,
                 hello_fields: Mapping[str, Any]) -> None:
        self.reader = reader
        self.hello_fields = hello_fields
        self._raw_write = write
        self.backend = backend
        self.startup_error = startup_error
        self.started = started
        self.idle_timeout_s = idle_timeout_s
        self.watchdog_s = watchdog_s
        self.greeted = False
        self.last_frame = time.monotonic()
        self._write_lock = threading.Lock()
        self._jobs: queue.Queue[p.Request | bytes | None] = queue.Queue()
        self._worker: threading.Thread | None = None
        self._closing = threading.Event()
        self._state = threading.Lock()  # guards the fields below
        self._pending = 0  # requests queued or running
        self._current: str | None = None  # the type of the request running
        self._seq = 0  # requests started so far
        self._idle_since = time.monotonic()
        self._exit: int | None = None  # set by the worker: the session is over
        self._watched = 0  # the request the watchdog last stopped

    # -- the reader -------------------------------------------------------------------
    def run(self) -> int:
        """Read and route frames until the session ends; returns the exit status."""
        try:
            while True:
                with self._state:
                    status, busy, idle_since = self._exit, self._pending > 0, self._idle_since
                if status is not None:
                    return status
                waiting_idle = not busy
                deadline = (max(self.last_frame, idle_since) + self.idle_timeout_s
                            if waiting_idle else time.monotonic() + POLL_S)
                try:
                    frame = self.reader.read_frame(deadline)
                except DeadlineExceeded:
                    if waiting_idle:
                        log.error("no frame from the controller in %.0f s; the controller or "
                                  "the link is dead: exiting WITHOUT moving the arms",
                                  self.idle_timeout_s)
                        return EXIT_IDLE
                    self._watch()
                    continue
                except LinkClosed:
                    self._abort("the controller closed the stream")
                    log.info("the controller closed the stream; closing the backend without "
                             "moving the arms")
                    return self._worker_status(EXIT_OK)
                except ProtocolError as exc:
                    self._abort("a broken frame")
                    log.error("%s; exiting without moving the arms", exc)
                    self._send(p.make_error(0, "protocol", str(exc), fatal=True))
                    return EXIT_PROTOCOL
                self.last_frame = time.monotonic()
                status = self._route(frame)
                if status is not None:
                    return status
        except (BrokenPipeError, ConnectionError) as exc:
            self._abort("the controller stopped reading")
            log.error("cannot write to the controller: %s; exiting without moving the arms",
                      exc)
            return EXIT_LINK

    def _route(self, frame: p.Frame) -> int | None:
        """Answer a frame at once, or queue it for the worker; an exit status ends it."""
        backend = self.backend
        try:
            req = p.parse_request(frame, backend.arm_names if backend else None)
        except ProtocolError as exc:
            self._in_order(p.make_error(frame.id, "protocol", str(exc)))
            return None
        if req.type == "stop":  # before hello too: stopping is always right
            self._stop(f"stop from the controller (request {req.id})")
            self._send(p.encode_frame({"type": "stop_ok", "id": req.id}))
            return None
        if not self.greeted:
            return self._before_hello(req)
        if req.type == "heartbeat":
            with self._state:
                busy = self._current
            self._send(p.encode_frame({"type": "heartbeat_ok", "id": req.id, "busy": busy,
                                       "uptime_s": round(time.monotonic() - self.started, 3)}))
            return None
        self._in_order(req)
        return None

    def _before_hello(self, req: p.Request) -> int | None:
        if req.type != "hello":
            self._send(p.make_error(req.id, "protocol", f"{req.type!r} before hello"))
            return None
        reply, status = self._hello(req)
        self._send(reply)
        if status is None:
            self.greeted = True
            self._worker = threading.Thread(target=self._work, name="agent-worker",
                                            daemon=True)
            self._worker.start()
        return status

    def _hello(self, req: p.Request) -> tuple[bytes, int | None]:
        """The reply to a hello, and the exit status if it ends the session."""
        if req.body["version"] != p.PROTOCOL_VERSION:
            why = (f"controller speaks protocol {req.body['version']}, this agent speaks "
                   f"{p.PROTOCOL_VERSION}; update the project on the host")
            return p.make_error(req.id, "version", why, fatal=True), EXIT_VERSION
        backend = self.backend
        if backend is None:
            assert self.startup_error is not None
            return p.make_error(req.id, "startup", self.startup_error[0],
                                traceback=self.startup_error[1], fatal=True), EXIT_STARTUP
        return p.encode_frame({"type": "hello_ok", "id": req.id,
                               "version": p.PROTOCOL_VERSION, "backend": backend.kind,
                               "arms": list(backend.arm_names),
                               "mirror": [bool(m) for m in backend.mirror],
                               "pid": os.getpid(), "build": build_id(),
                               **self.hello_fields}), None

    def _in_order(self, job: p.Request | bytes) -> None:
        """After hello: to the worker, behind the requests before it (a reply as bytes:
        an error for a request that could not be parsed). Before hello: at once."""
        if not self.greeted:
            assert isinstance(job, bytes)
            self._send(job)
            return
        with self._state:
            self._pending += 1
        self._jobs.put(job)

    def _watch(self) -> None:
        """The watchdog: a request runs, and the controller has said nothing for
        ``watchdog_s``: the link stopped answering and nobody watches the robot."""
        if self.watchdog_s is None:
            return
        silent = time.monotonic() - self.last_frame
        with self._state:
            current, seq = self._current, self._seq
            due = current is not None and seq != self._watched and silent >= self.watchdog_s
            if due:
                self._watched = seq
        if due:
            log.error("watchdog: no frame from the controller for %.1f s during %s; "
                      "stopping the motion (the link stopped answering, nobody watches the "
                      "robot)", silent, current)
            self._stop("the watchdog")

    def _stop(self, why: str) -> None:
        """``backend.stop()``, never raising (the reader must go on)."""
        backend = self.backend
        if backend is None:
            return
        with self._state:
            current = self._current
        t0 = time.monotonic()
        try:
            backend.stop()
        except Exception:  # say it; the caller goes on as if stopped
            log.exception("stopping the backend (%s) failed", why)
            return
        took = time.monotonic() - t0
        log.log(logging.WARNING if took > STOP_LIMIT_S else logging.INFO,
                "stopped the backend (%s) during %s in %.3f s%s", why, current or "no request",
                took, " (HostBackend.stop must return within 0.5 s)"
                if took > STOP_LIMIT_S else "")

    def _abort(self, why: str) -> None:
        """The controller is gone: run nothing more, stop the motion in progress."""
        self._closing.set()
        with self._state:
            running = self._current is not None
        if running:
            self._stop(why)

    def _worker_status(self, default: int) -> int:
        """At EOF: the worker's own ending (a broken pipe) if it had one, else ``default``."""
        self._drain()
        with self._state:
            return self._exit if self._exit is not None else default

    def _send(self, data: bytes) -> None:
        with self._write_lock:
            self._raw_write(data)

    # -- the worker -------------------------------------------------------------------
    def _work(self) -> None:
        """Run the queued requests one by one, in order, until told to stop."""
        while True:
            job = self._jobs.get()
            if job is None or self._closing.is_set():
                return
            with self._state:
                self._current = job.type if isinstance(job, p.Request) else "error"
                self._seq += 1
            status: int | None = None
            try:
                status = self._do(job)
            except (BrokenPipeError, ConnectionError) as exc:
                log.error("cannot write to the controller: %s; exiting without moving the "
                          "arms", exc)
                status = EXIT_LINK
            except Exception as exc:  # a bug of ours: say it, answer it, keep serving
                log.exception("serving %s", self._current)
                if isinstance(job, p.Request):
                    with contextlib.suppress(Exception):
                        self._reply(p.make_error(job.id, "backend",
                                                 f"{type(exc).__name__}: {exc}",
                                                 traceback=traceback.format_exc()))
            with self._state:
                self._current = None
                self._pending -= 1
                self._idle_since = time.monotonic()
                if status is not None:
                    self._exit = status
            if status is not None:
                self._closing.set()
                return

    def _do(self, job: p.Request | bytes) -> int | None:
        """One request: its reply (dropped once the controller is gone); bye ends it."""
        backend = self.backend
        assert backend is not None
        if isinstance(job, bytes):
            self._reply(job)
            return None
        if job.type == "bye":
            # Rest BEFORE bye_ok: the controller's close waits for it, so the arms are
            # out of the way when the agent is gone.
            log.info("bye: arms to rest, then exiting")
            try:
                backend.rest()
            except Exception:
                log.exception("rest at bye failed")
            self._reply(p.encode_frame({"type": "bye_ok", "id": job.id}))
            return EXIT_OK
        if job.type == "hello":  # again: the same answer
            reply, status = self._hello(job)
            self._reply(reply)
            return status
        self._reply(_dispatch(backend, job))
        prepare = getattr(backend, "prepare", None)
        if job.type in ("push", "reset") and prepare is not None and not self._closing.is_set():
            try:  # the next observation, while the controller is busy elsewhere
                prepare()
            except Exception:  # observe will try again and report it
                log.exception("preparing the next observation")
        return None

    def _reply(self, data: bytes) -> None:
        if not self._closing.is_set():  # the controller is gone: nobody reads it
            self._send(data)

    # -- the end ----------------------------------------------------------------------
    def _drain(self) -> None:
        """Let the worker finish the request it is in (after a stop), bounded."""
        worker = self._worker
        if worker is None or not worker.is_alive():
            return
        self._closing.set()
        self._jobs.put(None)
        worker.join(DRAIN_S)
        if worker.is_alive():
            log.error("the backend did not return from %s within %.0f s; closing it anyway",
                      self._current, DRAIN_S)

    def finish(self) -> None:
        """The worker ended, then the backend closed: never rest here, an orphaned agent
        does not move."""
        self._drain()
        if self.backend is not None:
            try:
                self.backend.close()
            except Exception:  # shutting down; say it and go on
                log.exception("closing the backend")


_CANNOT: dict[str, str] = {
    "reseed": "be reseeded", "frame": "take a full camera frame",
    "move_tcp": "move a TCP to a point", "save_calibration": "save a calibration",
    "describe": "describe a robot controller"}


def _observe_reply(backend: HostBackend, mid: int) -> bytes:
    """Views for the arms that have one; the others' errors (that arm alone faults).

    A backend says an arm has no view by leaving it out, or by giving an exception or a
    :class:`~drivers.wire.ArmFailed` in its place."""
    got: dict[str, object] = dict(backend.observe())
    views: dict[str, ArmView] = {}
    errors: dict[str, str] = {}
    for arm in backend.arm_names:
        v = got.get(arm)
        if isinstance(v, ArmView):
            views[arm] = v
        elif isinstance(v, p.ArmFailed):
            errors[arm] = v.error
        elif isinstance(v, BaseException):
            errors[arm] = f"{type(v).__name__}: {v}"
        else:
            errors[arm] = f"the backend returned no view for arm {arm!r}"
    return p.make_observe_reply(mid, views, errors)


def _dispatch(backend: HostBackend, req: p.Request) -> bytes:
    """The reply to one ordered request; a backend's exception becomes an error frame:
    a ``BackendError`` (an expected refusal) with its message alone, anything else with
    its traceback, for the operator's log."""
    try:
        if req.type == "observe":
            return _observe_reply(backend, req.id)
        if req.type == "push":
            return p.make_push_reply(req.id, backend.push(req.body["faces"]))
        if req.type == "reset":
            return p.make_reset_reply(req.id, backend.reset(req.body["arms"]))
        if req.type == "rest":
            backend.rest()
            return p.encode_frame({"type": "rest_ok", "id": req.id})
        if req.type == "reseed":
            backend.reseed(req.body["seed"])
            return p.encode_frame({"type": "reseed_ok", "id": req.id})
        if req.type == "frame":
            return p.make_frame_reply(req.id, backend.frame())
        if req.type == "move_tcp":
            tcp = backend.move_tcp(req.body["arm"], req.body["xyz_mm"])
            return p.encode_frame({"type": "move_tcp_ok", "id": req.id,
                                   "tcp": [float(v) for v in tcp]})
        if req.type == "save_calibration":
            path = backend.save_calibration(req.body["arm"], req.body["data"])
            return p.encode_frame({"type": "save_calibration_ok", "id": req.id,
                                   "path": str(path)})
        if req.type == "describe":
            return p.encode_frame({"type": "describe_ok", "id": req.id,
                                   "info": backend.describe()})
        return p.make_error(req.id, "protocol", f"unhandled request {req.type!r}")
    except NotImplementedError as exc:
        what = _CANNOT.get(req.type, f"do {req.type!r}")
        return p.make_error(req.id, "request", f"this backend ({backend.kind}) cannot {what}"
                            f"{f': {exc}' if str(exc) else ''}", arm=req.body.get("arm"))
    except ValueError as exc:
        return p.make_error(req.id, "request", str(exc), traceback=traceback.format_exc(),
                            arm=getattr(exc, "arm", None))
    except BackendError as exc:  # an expected refusal: one line for the operator
        log.warning("%s refused: %s", req.type, exc)
        return p.make_error(req.id, "backend", str(exc) or type(exc).__name__,
                            arm=getattr(exc, "arm", None))
    except Exception as exc:  # the controller decides; we keep serving
        log.exception("%s failed", req.type)
        return p.make_error(req.id, "backend", f"{type(exc).__name__}: {exc}",
                            traceback=traceback.format_exc(), arm=getattr(exc, "arm", None))


def _pairs(values: Sequence[str], flag: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for v in values:
        arm, sep, rest = v.partition("=")
        if not sep or not arm or not rest:
            raise SystemExit(f"{flag} expects ARM=VALUE, got {v!r}")
        out[arm] = rest
    return out


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="python -m drivers.agent",
                                 description="Serve one robot host's arms on stdin/stdout.")
    ap.add_argument("--backend", choices=("twin", "yumi"), required=True)
    ap.add_argument("--host", default="host", help="host name, for messages")
    ap.add_argument("--arms", default="left,right")
    ap.add_argument("--mirror", default=None, help="0/1 per arm (default: right arms mirror)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-physics", action="store_true",
                    help="twin: canned images, no simulation (benchmarks)")
    ap.add_argument("--camera", default=None, help="yumi: device index or video file")
    ap.add_argument("--controller-url", default=None, help="yumi: RWS URL of the controller")
    ap.add_argument("--crop", action="append", default=[], metavar="ARM=x0,y0,x1,y1")
    ap.add_argument("--calibration", action="append", default=[], metavar="ARM=FILE")
    ap.add_argument("--calibrate", action="append", default=[], metavar="ARM",
                    help="yumi: this arm is being calibrated (provisional calibration; "
                         "frame, move_tcp, rest and save_calibration only); repeatable")
    ap.add_argument("--lock-dir", default=None,
                    help="directory of the per-robot lock files, shared by every user of "
                         "the host (default /run/lock/fleet-testbed)")
    ap.add_argument("--lock-id", default=None,
                    help="lock this identity (default: yumi: the controller's serial, else "
                         "its URL; twin: no lock, every twin agent owns its own cell)")
    ap.add_argument("--idle-timeout", type=float, default=120.0,
                    help="exit (arms NOT moved) after this long without a frame")
    ap.add_argument("--watchdog", type=float, default=None, metavar="S",
                    help="while a request runs, stop the motion if no frame at all came "
                         "from the controller for S seconds (the controller heartbeats "
                         "during motions; default: no watchdog)")
    ap.add_argument("--credentials-file", default=None, metavar="FILE",
                    help="yumi: the controller's login, one line USER:PASSWORD, mode 0600")
    ap.add_argument("--motion-timeout", type=float, default=None, metavar="S",
                    help="yumi: stop a motion program that runs longer than S seconds")
    ap.add_argument("--camera-settings", default=None, metavar="JSON",
                    help="yumi: the camera's settings, a JSON object of width, height, "
                         "fourcc, fps, exposure, white_balance, focus (set on a V4L2 "
                         "camera when it opens, and read back)")
    ap.add_argument("--chdir", default=None, help="working directory (the project checkout)")
    return ap.parse_args(argv)


BackendFactory = Callable[[argparse.Namespace, dict[str, Any]], "HostBackend"]
"""``(args, kwargs) -> backend``: how :func:`main` builds its backend from the parsed
argv and the keyword arguments of ``drivers.backends.make_backend`` it derived."""


def _backend_kwargs(args: argparse.Namespace) -> dict[str, Any] | str:
    """``make_backend``'s keyword arguments from the argv, or what is wrong with it.

    ``credentials_file`` and ``motion_timeout_s`` only when given, so a backend factory
    that does not know them yet still builds the backends that do not need them."""
    arms = [a for a in args.arms.split(",") if a]
    if args.mirror is None:
        mirror = [a.startswith("right") for a in arms]
    else:
        mirror = [m.strip() in ("1", "true") for m in args.mirror.split(",")]
    if len(mirror) != len(arms):
        return f"--mirror needs one value per arm ({len(arms)})"
    crops: dict[str, tuple[int, int, int, int]] = {}
    for arm, box in _pairs(args.crop, "--crop").items():
        try:
            x0, y0, x1, y1 = (int(v) for v in box.split(","))
        except ValueError:
            return f"--crop {arm}=... needs four integers"
        crops[arm] = (x0, y0, x1, y1)
    kwargs: dict[str, Any] = dict(
        arms=arms, mirror=mirror, seed=args.seed, physics=not args.no_physics, crops=crops,
        calibrations=_pairs(args.calibration, "--calibration"), camera=args.camera,
        controller_url=args.controller_url, calibrating=args.calibrate)
    if args.credentials_file is not None:
        kwargs["credentials_file"] = args.credentials_file
    if args.motion_timeout is not None:
        kwargs["motion_timeout_s"] = args.motion_timeout
    if args.camera_settings is not None:  # the JSON text: the camera validates it
        kwargs["camera_settings"] = args.camera_settings
    return kwargs


def _controller_info(args: argparse.Namespace) -> dict[str, str] | None:
    """A YuMi's controller as it names itself (serial, RobotWare, system: one read-only
    login, before the lock), for the lock and for hello_ok ``controller``; None for a
    twin, or when the controller cannot be asked."""
    if args.backend != "yumi" or not args.controller_url:
        return None
    from drivers.yumi.rws_controller import controller_info

    return controller_info(args.controller_url, args.credentials_file)


def _robot_identity(args: argparse.Namespace, controller: Mapping[str, str] | None
                    ) -> str | None:
    """What this agent must own exclusively: ``--lock-id``; a YuMi as its controller
    names itself (``controller``'s serial) or else its normalised URL; None for a twin
    (it owns its own cell)."""
    if args.lock_id or args.backend != "yumi" or not args.controller_url:
        return lock_identity(args.backend, args.controller_url, args.lock_id)
    from drivers.yumi.rws_controller import robot_identity

    return (robot_identity(controller)
            or lock_identity(args.backend, args.controller_url, None))


def _make_backend(args: argparse.Namespace, kwargs: dict[str, Any]) -> HostBackend:
    """The product's backends (twin, yumi), imported only now (pybullet prints)."""
    from drivers.backends import make_backend

    return make_backend(args.backend, **kwargs)


def main(argv: Sequence[str] | None = None, *,
         backend_factory: BackendFactory | None = None) -> int:
    """The agent process. ``backend_factory``: the tests' seam (their own backend, e.g.
    an arm that moves for seconds, behind the real agent: ``tests/drivers/slow_arm.py``);
    the command line never reaches it."""
    frames_fd = claim_stdout()
    args = parse_args(argv)
    logging.basicConfig(stream=sys.stderr, level=logging.WARNING,
                        format=f"%(asctime)s agent[{args.host}] %(levelname)s %(message)s")
    log.setLevel(logging.INFO)  # our lifecycle lines (a few per session), not others
    if args.chdir:
        os.chdir(args.chdir)
    kwargs = _backend_kwargs(args)
    if isinstance(kwargs, str):
        print(kwargs, file=sys.stderr)
        return EXIT_USAGE
    build = backend_factory or _make_backend
    log.info("agent pid %d for host %s: backend %s, protocol %d, build %s", os.getpid(),
             args.host, args.backend, p.PROTOCOL_VERSION, build_id())
    held: list[RobotLock] = []
    hello_fields: dict[str, Any] = {}

    def factory() -> HostBackend:
        controller = _controller_info(args)
        if controller is not None:
            hello_fields["controller"] = controller
        identity = _robot_identity(args, controller)
        if identity is not None:  # before anything moves the robot (refusal: at hello)
            lock = RobotLock(identity, args.lock_dir or default_lock_dir(), args.host,
                             controller=args.controller_url)
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


if __name__ == "__main__":
    sys.exit(main())
