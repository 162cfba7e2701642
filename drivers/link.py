"""The controller's end of one agent connection: handshake, then request/reply.

Why separate from the transport and the worker: this is where bytes become checked
messages. Every call has a deadline; every reply is checked against the request (type,
id, arm set) by ``drivers.wire``; when the stream breaks, the error carries what the
agent left behind (exit status, end of its stderr: e.g. the traceback of a crash at
import), so the operator reads *why* and not a bare EOF.

Two threads may write on one link (protocol 3): the fleet's call, and a heartbeat or a
stop sent write-only (:meth:`AgentLink.send_only`) while that call waits for its reply.
A write lock keeps every frame whole, and the call's reader skips the ``heartbeat_ok``
and ``stop_ok`` it is not waiting for (the agent answers those at once, so they may come
before, between or after the call's replies); ``skipped`` keeps the latest of them.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any

from drivers import wire as p
from drivers.backends.base import ArmOutcome, ArmView
from drivers.build_id import BuildMismatch, build_id, matches, mismatch_line
from drivers.errors import DeadlineExceeded, LinkClosed, ProtocolError, TruncatedFrame
from drivers.transport import Transport
from testbed.core.host_config import HostConfig

SKIPPED_KEEP = 256


class AgentLink:
    """One live connection to one host's agent.

    One caller makes the calls (reads); any thread may :meth:`send_only` a heartbeat or
    a stop meanwhile (writes are serialised by the link's write lock)."""

    def __init__(self, host: HostConfig, transport: Transport) -> None:
        self.host = host
        self.transport = transport
        self.peer = transport.peer
        self.reader = p.FrameReader(transport.read, self.peer)
        self.info: p.HelloInfo | None = None
        self.last_io = time.monotonic()
        """When a frame last came from the agent."""
        self.last_write = self.last_io
        """When a frame last went to the agent (the heartbeat's cadence during a call)."""
        self.skipped: deque[tuple[float, dict[str, Any]]] = deque(maxlen=SKIPPED_KEEP)
        """(time.monotonic(), header) of the latest replies skipped by a read: the
        heartbeat_ok and stop_ok of requests sent write-only."""
        self._next_id = 1
        self._write_lock = threading.Lock()

    @property
    def arms(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.host.arms)

    def _explain(self, exc: LinkClosed | ProtocolError | DeadlineExceeded) -> Exception:
        if isinstance(exc, LinkClosed | TruncatedFrame):
            # The stream ended: the agent is most likely exiting right now, and its exit
            # status tells why (a crash, a kill). Wait for it briefly, never long.
            wait_until = time.monotonic() + 0.2
            while self.transport.exit_status() is None and time.monotonic() < wait_until:
                time.sleep(0.005)
        diag = self.transport.diagnostics()
        return type(exc)(f"{exc}\n{diag}" if diag else str(exc))

    def send(self, mtype: str, deadline: float, **fields: Any) -> int:
        """Write one request; returns its id. Requests may be pipelined."""
        mid = self._write(mtype, deadline, fields)
        if mid is None:
            raise self._explain(DeadlineExceeded(
                f"{self.peer}: the link was busy writing past the deadline")) from None
        return mid

    def send_only(self, mtype: str, deadline: float, **fields: Any) -> int | None:
        """Write a request whose reply nobody waits for (a heartbeat or a stop during a
        call): the read that meets its reply skips it. None if another frame was being
        written until the deadline (nothing written: the stream is intact)."""
        return self._write(mtype, deadline, fields)

    def _write(self, mtype: str, deadline: float, fields: Mapping[str, Any]) -> int | None:
        if not self._write_lock.acquire(timeout=max(deadline - time.monotonic(), 0.0)):
            return None
        try:
            mid = self._next_id
            self._next_id = mid % p.MAX_ID + 1
            try:
                self.transport.write(p.make_request(mtype, mid, **fields), deadline)
            except (LinkClosed, DeadlineExceeded) as exc:
                raise self._explain(exc) from None
            self.last_write = time.monotonic()
            return mid
        finally:
            self._write_lock.release()

    def receive(self, mtype: str, mid: int, deadline: float) -> p.Frame:
        """Read the reply to request ``mid``; ``error`` replies raise (AgentError...).

        A ``heartbeat_ok`` or ``stop_ok`` with another id is the late reply of a request
        sent write-only: recorded in ``skipped``, never taken for this reply."""
        while True:
            try:
                frame = self.reader.read_frame(deadline)
            except (LinkClosed, ProtocolError, DeadlineExceeded) as exc:
                raise self._explain(exc) from None
            self.last_io = time.monotonic()
            if frame.type in p.AT_ONCE_REPLIES and frame.id != mid:
                self.skipped.append((self.last_io, frame.header))
                continue
            return p.check_reply(frame, f"{mtype}_ok", mid, self.peer)

    def call(self, mtype: str, deadline: float, **fields: Any) -> p.Frame:
        return self.receive(mtype, self.send(mtype, deadline, **fields), deadline)

    def open(self, argv: list[str], timeout_s: float) -> p.HelloInfo:
        """Start the agent and shake hands; the agent must serve the configured arms and
        run this controller's build (BuildMismatch otherwise: nothing was asked of the
        arms yet, and closing the link leaves them where they are)."""
        deadline = time.monotonic() + timeout_s
        self.transport.open(argv, timeout_s)
        frame = self.call("hello", deadline, version=p.PROTOCOL_VERSION, host=self.host.name)
        info = p.parse_hello_reply(frame, self.peer)
        if info.version != p.PROTOCOL_VERSION:
            raise ProtocolError(f"{self.peer} speaks protocol {info.version}, we speak "
                                f"{p.PROTOCOL_VERSION}")
        mirror = tuple(a.mirror for a in self.host.arms)
        if info.arms != self.arms or info.mirror != mirror:
            raise ProtocolError(f"{self.peer} serves arms {list(info.arms)} (mirror "
                                f"{list(info.mirror)}) but the config names {list(self.arms)} "
                                f"(mirror {list(mirror)})")
        if not matches(info.build):
            raise BuildMismatch(mismatch_line(self.host.name, info.build, build_id(),
                                              self.host.workdir))
        self.info = info
        return info

    def observe(self, deadline: float) -> dict[str, ArmView]:
        return p.parse_observe_reply(self.call("observe", deadline), self.arms, self.peer)

    def push(self, faces: Mapping[str, int], deadline: float) -> dict[str, ArmOutcome]:
        frame = self.call("push", deadline, faces=dict(faces))
        return p.parse_push_reply(frame, list(faces), self.peer)

    def reset(self, arms: Sequence[str], deadline: float) -> dict[str, bool]:
        frame = self.call("reset", deadline, arms=list(arms))
        return p.parse_reset_reply(frame, list(arms), self.peer)

    def rest(self, deadline: float) -> None:
        self.call("rest", deadline)

    def heartbeat(self, deadline: float) -> None:
        self.call("heartbeat", deadline)

    def bye(self, deadline: float) -> None:
        self.call("bye", deadline)

    def close(self) -> None:
        self.transport.close()
