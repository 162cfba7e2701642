"""One controller's session with the agent: the reader, the one worker, the end.

Why two threads (protocol 3): a push on a real arm is a motion of seconds. While it runs
the reader still hears the controller: heartbeats are answered (the controller knows the
agent lives), and ``stop`` reaches ``backend.stop()`` at once instead of waiting behind
the motion it should stop. Every other request goes, in order, to the one worker
(``agent_dispatch.dispatch``). The lifecycle is drawn in ``drivers/agent/__init__.py``.
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import threading
import time
import traceback
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

from drivers import wire as p
from drivers.agent.agent_dispatch import dispatch
from drivers.agent.agent_watchdog import Watchdog, stop_backend
from drivers.build_id import build_id
from drivers.errors import DeadlineExceeded, LinkClosed, ProtocolError
from drivers.hostlock import RobotBusy

if TYPE_CHECKING:
    from drivers.backends.base import HostBackend

__all__ = ["EXIT_IDLE", "EXIT_LINK", "EXIT_OK", "EXIT_PROTOCOL", "EXIT_STARTUP",
           "EXIT_USAGE", "EXIT_VERSION", "serve"]

EXIT_OK = 0
EXIT_USAGE = 2
EXIT_PROTOCOL = 3
EXIT_VERSION = 4
EXIT_STARTUP = 5
EXIT_IDLE = 6
EXIT_LINK = 7

log = logging.getLogger("drivers.agent")


POLL_S = 0.05
"""While a request runs, the reader waits for frames in slices this long, so it notices
at once the worker ending the session (bye, a broken link) and the watchdog's silence."""
DRAIN_S = 10.0
"""At exit, how long the backend may take to return from a stopped request before it is
closed anyway."""
MAY_MOVE = ("observe", "push", "reset", "rest", "move_tcp")
"""The requests that may move an arm (a YuMi's picture step sends an arm in view to
rest). Bye rests the arms only after one of them: a session that only looked (hello,
describe, frame: ``testbed check``, the check a trial runs first) ends as it found the
arms, so a check that refuses an arm where it is never moves it (issue 43)."""


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
        self._may_have_moved = False  # a MAY_MOVE request was run (the worker's own)
        self.watchdog = Watchdog(watchdog_s)

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
        """The watchdog's turn: a request runs and the controller may have gone silent."""
        silent = time.monotonic() - self.last_frame
        with self._state:
            current, seq = self._current, self._seq
        if self.watchdog.due(silent, current, seq):
            stop_backend(self.backend, "the watchdog", current)

    def _stop(self, why: str) -> None:
        """``backend.stop()``, never raising (the reader must go on)."""
        with self._state:
            current = self._current
        stop_backend(self.backend, why, current)

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
            # out of the way when the agent is gone; only after a request that may have
            # moved one (MAY_MOVE): a session that only looked leaves them as it found them.
            if not self._may_have_moved:
                log.info("bye: this session only looked (no request that moves an arm); "
                         "exiting without a motion")
            else:
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
        if job.type in MAY_MOVE:
            self._may_have_moved = True
        self._reply(dispatch(backend, job))
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
