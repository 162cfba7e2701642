"""The worker process of one host: owns its agent link, heartbeats it, reconnects it.

Why one process per HOST (not per arm): a host's two arms share one camera (one
picture for both) and one robot controller (one MultiMove program moves both at once),
so they are one agent and one link; two workers would have to share that link again.
Why a PROCESS (not a thread in the controller): the controller process also trains the
policy, and paramiko's packet handling and PNG decoding are CPU work under the GIL;
processes keep the hosts parallel with each other and with training, and a crash in
native code (cv2, crypto) takes down one host, not the trial.

::

    HostFleet (controller) ══ socketpair (pickles) ══ HostWorker (this module)
                                                         │ main thread: calls, heartbeat
                                                         │ connector thread: (re)connect
                                                         ▼  with exponential backoff
                                                  AgentLink ── Transport ── agent

Messages on the socketpair: parent -> worker ``("call", rid, op, args)`` / ``("close", rid)``;
worker -> parent ``("reply", rid, "ok", payload)``, ``("reply", rid, "fault", info)``
and unsolicited ``("status", info)`` when the link comes up or goes down. A worker never
lets an exception escape a call: it answers ``fault`` with the host, the arm when
known, and the traceback (as Gymnasium's AsyncVectorEnv), and drops the link when the
stream can no longer be trusted. While the link is down, calls are answered at once.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time
import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

from drivers.errors import AgentError, DeadlineExceeded, DriverError, LinkClosed
from drivers.link import AgentLink
from drivers.transport import LocalTransport, agent_argv, make_transport
from testbed.config import HostConfig

MAX_BACKOFF_S = 30.0


@dataclass(frozen=True, slots=True)
class WorkerSpec:
    host: HostConfig
    seed: int
    backoff_s: float
    heartbeat_s: float
    connect_timeout_s: float
    idle_timeout_s: float


def main(argv: list[str] | None = None) -> int:
    """``python -m drivers.worker FD``: FD is this worker's end of a socketpair."""
    # The controller handles Ctrl-C (arms to rest, then close); a worker must outlive it.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    args = sys.argv[1:] if argv is None else argv
    conn = Connection(int(args[0]))
    try:
        spec = conn.recv()
    except (EOFError, OSError):
        return 1
    HostWorker(conn, spec).run()
    return 0


def _fault(reason: str, tb: str = "", arm: str | None = None) -> dict[str, Any]:
    return {"reason": reason, "traceback": tb, "arm": arm}


class HostWorker:
    def __init__(self, conn: Connection, spec: WorkerSpec) -> None:
        self.conn = conn
        self.spec = spec
        self.host = spec.host
        self.link: AgentLink | None = None
        self._cond = threading.Condition()
        self._send_lock = threading.Lock()
        self._closing = False
        self._attempt = 0
        self._next_attempt = 0.0
        self._down_since = time.monotonic()
        self._last_error = "not connected yet"
        self._last_tb = ""

    # -- pipe --------------------------------------------------------------------------
    def send(self, msg: tuple[Any, ...]) -> None:
        # If the parent is gone, the main loop notices (EOF) and exits.
        with self._send_lock, contextlib.suppress(OSError, ValueError):
            self.conn.send(msg)

    # -- link lifecycle -----------------------------------------------------------------
    def _argv(self) -> list[str]:
        h = self.host
        python = LocalTransport.python_for(h) if h.transport == "local" else h.python
        return agent_argv(h, seed=self.spec.seed, python=python,
                          idle_timeout_s=self.spec.idle_timeout_s)

    def _connector(self) -> None:
        while True:
            with self._cond:
                while not self._closing and (self.link is not None
                                             or time.monotonic() < self._next_attempt):
                    wait = None if self.link is not None else self._next_attempt - time.monotonic()
                    self._cond.wait(wait if wait is None else max(wait, 0.0))
                if self._closing:
                    return
            link = AgentLink(self.host, make_transport(self.host))
            try:
                info = link.open(self._argv(), self.spec.connect_timeout_s)
            except Exception as exc:
                self._close_async(link)
                with self._cond:
                    self._attempt += 1
                    backoff = min(self.spec.backoff_s * 2 ** (self._attempt - 1), MAX_BACKOFF_S)
                    self._next_attempt = time.monotonic() + backoff
                    self._last_error = _describe(exc)
                    self._last_tb = _remote_tb(exc)
                self.send(("status", self._status(next_in=backoff)))
                continue
            with self._cond:
                if self._closing:
                    self._close_async(link)
                    return
                self.link = link
                self._attempt = 0
            self.send(("status", self._status(info={
                "backend": info.backend, "pid": info.pid, "version": info.version})))

    def _status(self, *, info: dict[str, Any] | None = None, next_in: float | None = None
                ) -> dict[str, Any]:
        up = self.link is not None
        return {"connected": up, "info": info or {}, "error": None if up else self._last_error,
                "traceback": None if up else self._last_tb, "attempt": self._attempt,
                "next_attempt_in": next_in, "at": time.time()}

    def _drop(self, link: AgentLink, exc: BaseException) -> None:
        """The stream can't be trusted: forget the link, reconnect in the background."""
        with self._cond:
            if self.link is link:
                self.link = None
                self._down_since = time.monotonic()
                self._last_error = _describe(exc)
                self._last_tb = _remote_tb(exc)
                self._attempt = 0
                self._next_attempt = time.monotonic() + self.spec.backoff_s
                self._cond.notify_all()
        self._close_async(link)
        self.send(("status", self._status(next_in=self.spec.backoff_s)))

    @staticmethod
    def _close_async(link: AgentLink) -> None:
        # Closing waits for the agent to exit (bounded, ~1 s); never on the call path.
        threading.Thread(target=link.close, daemon=True, name="link-reaper").start()

    def _down_reason(self) -> str:
        with self._cond:
            since = time.monotonic() - self._down_since
            nxt = max(self._next_attempt - time.monotonic(), 0.0)
            return (f"host {self.host.name} is unreachable (down {since:.1f} s; reconnecting, "
                    f"attempt {self._attempt + 1} in {nxt:.1f} s): {self._last_error}")

    # -- calls --------------------------------------------------------------------------
    def _do(self, link: AgentLink, op: str, args: dict[str, Any]) -> Any:
        deadline = time.monotonic() + self.host.deadline_s
        if op == "observe":
            return link.observe(deadline)
        if op == "execute":
            out: dict[str, Any] = {"reset": {}, "push": {}}
            if args["resets"]:
                out["reset"] = link.reset(args["resets"], deadline)
                deadline = time.monotonic() + self.host.deadline_s
            if args["faces"]:
                out["push"] = link.push(args["faces"], deadline)
            return out
        if op == "rest":
            link.rest(deadline)
            return None
        raise ValueError(f"unknown worker op {op!r}")

    def _call(self, rid: int, op: str, args: dict[str, Any]) -> None:
        link = self.link
        if link is None:
            self.send(("reply", rid, "fault", _fault(self._down_reason(), self._last_tb)))
            return
        try:
            result = self._do(link, op, args)
        except AgentError as exc:
            if exc.fatal:
                self._drop(link, exc)
            self.send(("reply", rid, "fault", _fault(str(exc), exc.remote_traceback, exc.arm)))
        except DriverError as exc:
            self._drop(link, exc)
            self.send(("reply", rid, "fault", _fault(_describe(exc), traceback.format_exc())))
        except Exception as exc:
            self._drop(link, exc)
            self.send(("reply", rid, "fault", _fault(
                f"host {self.host.name}: worker error in {op}: {type(exc).__name__}: {exc}",
                traceback.format_exc())))
        else:
            self.send(("reply", rid, "ok", result))

    def _heartbeat(self) -> None:
        link = self.link
        if link is None or time.monotonic() - link.last_io < self.spec.heartbeat_s:
            return
        try:
            link.heartbeat(time.monotonic() + self.host.deadline_s)
        except Exception as exc:
            self._drop(link, exc)

    def run(self) -> None:
        connector = threading.Thread(target=self._connector, daemon=True, name="connector")
        connector.start()
        try:
            while True:
                link = self.link
                wait = (self.spec.heartbeat_s - (time.monotonic() - link.last_io)
                        if link is not None else 0.5)
                try:
                    if not self.conn.poll(max(wait, 0.0)):
                        self._heartbeat()
                        continue
                    msg = self.conn.recv()
                except (EOFError, OSError):
                    return  # the controller is gone
                if msg[0] == "close":
                    self._shutdown()
                    self.send(("reply", msg[1], "ok", None))
                    return
                if msg[0] == "call":
                    self._call(msg[1], msg[2], msg[3])
        finally:
            with self._cond:
                self._closing = True
                link, self.link = self.link, None
                self._cond.notify_all()
            if link is not None:
                link.close()

    def _shutdown(self) -> None:
        with self._cond:
            self._closing = True
            link, self.link = self.link, None
            self._cond.notify_all()
        if link is not None:
            with contextlib.suppress(Exception):  # the agent also rests and exits on EOF
                link.bye(time.monotonic() + min(self.host.deadline_s, 5.0))
            link.close()


def _describe(exc: BaseException) -> str:
    if isinstance(exc, DriverError):
        kind = {LinkClosed: "link closed", DeadlineExceeded: "deadline exceeded"}.get(
            type(exc), type(exc).__name__)
        return f"{kind}: {exc}"
    return f"{type(exc).__name__}: {exc}"


def _remote_tb(exc: BaseException) -> str:
    if isinstance(exc, AgentError) and exc.remote_traceback:
        return exc.remote_traceback
    return "".join(traceback.format_exception(exc))


if __name__ == "__main__":
    sys.exit(main())
