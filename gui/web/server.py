"""The web console's server: Starlette routes, a frame hub, uvicorn in a thread.

Why Starlette on uvicorn: Starlette is the small, maintained ASGI toolkit (HTTP and
WebSocket routes, nothing else we do not use) and uvicorn its reference server, with
TLS from a certificate and key file built in; both are pure Python wheels. The server
runs its own asyncio loop in one thread of the controller, so the fleet loop stays
synchronous: the console hands frames over through ``FrameHub`` (latest only, never
blocking) and inputs come back through the ``Owner``'s methods, run in worker threads
so a slow render never stalls the event loop.

Wire (all behind a valid token, ``?token=``; a bad or missing one gets 401 and no
page, and a socket is refused before it opens)::

    GET /?token=T              the page of T's human
    GET /overview?token=T      the fleet overview: the operator's token with pause and
                               stop, the overview token or a human's to look at only
    WS  /ws?token=T            server -> page: binary frames (u32 header length, JSON
                                 header, PNG), JSON texts ("input" replies, "fleet":
                                 the latest counters and modes, for a page with no arm)
                               page -> server: {"type": "key", "key", "seq"},
                                 {"type": "click", "x", "y", "seq"},
                                 {"type": "button", "name", "seq"},
                                 {"type": "painted", "seq", "t_sent", "t_painted"}
    WS  /ws/overview?token=T   the same for the overview surface ("history", no "fleet")

``seq`` is the number of the frame on screen when the human acted: an input counts
only for the request that frame showed (``gui.desk``), so an action for a step that
is over is refused, never applied to the next.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import HTMLResponse, PlainTextResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect

from gui.console_core import OVERVIEW
from gui.errors import ConsoleUnavailable
from gui.web.tokens import OPERATOR

log = logging.getLogger(__name__)

PING_S = 5.0
"""WebSocket ping interval and timeout: a page whose network vanished without closing
(dropped Wi-Fi) is seen gone within about two of these, and its human marked away."""
NO_STORE = {"Cache-Control": "no-store", "Referrer-Policy": "no-referrer",
            "X-Content-Type-Options": "nosniff"}
UNAUTHORIZED = "401: this console needs a valid token (the URL printed at start)\n"
READ_ONLY = ("this overview link is to look at: pause and stop are the operator's (their "
             "own overview link, or Ctrl-C where the trial runs)")
POLICY_VIOLATION = 1008


class Owner(Protocol):
    """What the server needs of the console that owns it (``WebHumans``)."""

    def human_of(self, token: str | None) -> int | None: ...

    def overview_role(self, token: str | None) -> str | None: ...

    def page(self, wid: int, controls: bool) -> str: ...

    def connected(self, wid: int) -> list[dict[str, Any]]: ...

    def disconnected(self, wid: int) -> None: ...

    def handle(self, wid: int, msg: Any) -> dict[str, Any] | None: ...


@dataclass(eq=False)
class _Subscriber:
    wid: int
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    texts: deque[str] = field(default_factory=deque)
    sent_version: int = -1
    fleet_version: int = -1


class FrameHub:
    """Latest frame per surface, handed from the console's threads to the sockets.

    ``post`` never blocks: it keeps the newest payload of a surface and wakes that
    surface's sockets on the server's loop; a socket that is behind skips to the
    newest frame (a human wants the present, not a backlog). ``post_fleet`` does the
    same for the fleet's state that every human page shows while it has no arm (one
    text for all of them; a page that opens later gets the latest at once).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._latest: dict[int, tuple[int, bytes, dict[str, Any]]] = {}
        self._fleet: tuple[int, str] | None = None
        self._version = 0
        self._subs: set[_Subscriber] = set()
        self.loop: asyncio.AbstractEventLoop | None = None

    def post(self, wid: int, payload: bytes, header: dict[str, Any]) -> None:
        with self._lock:
            self._version += 1
            self._latest[wid] = (self._version, payload, header)
            loop = self.loop
        if loop is not None:
            with contextlib.suppress(RuntimeError):  # the loop is closing
                loop.call_soon_threadsafe(self._wake, wid)

    def post_fleet(self, doc: dict[str, Any]) -> None:
        """The fleet's latest state for the human pages (JSON text ``doc``)."""
        text = json.dumps(doc)
        with self._lock:
            self._version += 1
            self._fleet = (self._version, text)
            loop = self.loop
        if loop is not None:
            with contextlib.suppress(RuntimeError):  # the loop is closing
                loop.call_soon_threadsafe(self._wake_human_pages)

    def latest(self, wid: int) -> tuple[int, bytes, dict[str, Any]] | None:
        with self._lock:
            return self._latest.get(wid)

    def latest_fleet(self) -> tuple[int, str] | None:
        with self._lock:
            return self._fleet

    def _wake(self, wid: int) -> None:
        for sub in self._subs:
            if sub.wid == wid:
                sub.wake.set()

    def _wake_human_pages(self) -> None:
        for sub in self._subs:
            if sub.wid != OVERVIEW:
                sub.wake.set()

    def subscribe(self, wid: int) -> _Subscriber:
        self.loop = asyncio.get_running_loop()
        sub = _Subscriber(wid)
        sub.wake.set()  # send the latest frame at once
        self._subs.add(sub)
        return sub

    def unsubscribe(self, sub: _Subscriber) -> None:
        self._subs.discard(sub)


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number a console sends")


def parse_message(text: str) -> Any:
    """A page's JSON message, or None if it is not one (never raises)."""
    try:
        return json.loads(text, parse_constant=_no_constant)
    except (ValueError, RecursionError):
        return None


def frame_message(payload: bytes, header: dict[str, Any]) -> bytes:
    """One binary WebSocket message: u32 big-endian header length, JSON header, PNG."""
    head = json.dumps(header | {"t_sent": time.time() * 1e3}).encode()
    return struct.pack(">I", len(head)) + head + payload


async def _send_loop(ws: WebSocket, hub: FrameHub, sub: _Subscriber) -> None:
    while True:
        await sub.wake.wait()
        sub.wake.clear()
        while sub.texts:
            await ws.send_text(sub.texts.popleft())
        latest = hub.latest(sub.wid)
        if latest is not None and latest[0] != sub.sent_version:
            sub.sent_version = latest[0]
            await ws.send_bytes(frame_message(latest[1], latest[2]))
        fleet = hub.latest_fleet() if sub.wid != OVERVIEW else None
        if fleet is not None and fleet[0] != sub.fleet_version:
            sub.fleet_version = fleet[0]
            await ws.send_text(fleet[1])


def build_app(owner: Owner, hub: FrameHub) -> Starlette:
    """The console's ASGI app: two pages and two sockets, every one behind a token."""

    def who(conn: Request | WebSocket, overview: bool) -> tuple[int, bool] | None:
        """The surface the token opens, and whether with the operator's controls: its
        human's page (no controls), or the overview (the operator's token: controls)."""
        token = conn.query_params.get("token")
        if overview:
            role = owner.overview_role(token)
            return None if role is None else (OVERVIEW, role == OPERATOR)
        human = owner.human_of(token)
        return None if human is None else (human, False)

    def page(overview: bool) -> Callable[[Request], Any]:
        async def handler(request: Request) -> Response:
            got = who(request, overview)
            if got is None:
                return PlainTextResponse(UNAUTHORIZED, status_code=401, headers=NO_STORE)
            return HTMLResponse(owner.page(*got), headers=NO_STORE)
        return handler

    def socket_route(overview: bool) -> Callable[[WebSocket], Any]:
        async def handler(ws: WebSocket) -> None:
            got = who(ws, overview)
            if got is None:
                await ws.close(code=POLICY_VIOLATION)  # before accept: the handshake fails
                return
            wid, controls = got
            await ws.accept()
            sub = hub.subscribe(wid)
            for text in await asyncio.to_thread(owner.connected, wid):
                sub.texts.append(json.dumps(text))
            sender = asyncio.create_task(_send_loop(ws, hub, sub))
            try:
                while True:
                    try:
                        msg = parse_message(await ws.receive_text())
                    except KeyError:  # a binary message
                        msg = None
                    if wid == OVERVIEW and not controls:  # a viewer: nothing it sends acts
                        got = msg if isinstance(msg, dict) else {}
                        reply = None if got.get("type") == "painted" else {
                            "type": "input", "taken": False, "why": READ_ONLY,
                            "seq": got.get("seq"), "id": got.get("id")}
                        if reply is not None:
                            sub.texts.append(json.dumps(reply))
                            sub.wake.set()
                        continue
                    try:
                        reply = await asyncio.to_thread(owner.handle, wid, msg)
                    except Exception as exc:  # an input must never drop the page
                        log.exception("web console: a message from %s failed", wid)
                        reply = {"type": "error", "why": f"the console failed on it ({exc})"}
                    if reply is not None:
                        sub.texts.append(json.dumps(reply))
                        sub.wake.set()
            except (WebSocketDisconnect, RuntimeError):
                pass
            finally:
                sender.cancel()
                hub.unsubscribe(sub)
                await asyncio.to_thread(owner.disconnected, wid)
        return handler

    return Starlette(routes=[
        Route("/", page(False)),
        Route("/overview", page(True)),
        WebSocketRoute("/ws", socket_route(False)),
        WebSocketRoute("/ws/overview", socket_route(True)),
    ])


class WebServer:
    """uvicorn serving an app from a thread of its own, on a socket bound here.

    The socket is bound in the caller's thread so a taken port or a bad address is a
    ``ConsoleUnavailable`` line at start, not a log line from a thread.
    """

    def __init__(self, app: Starlette, host: str, port: int, *,
                 certfile: str | None = None, keyfile: str | None = None) -> None:
        import uvicorn  # lazy: the web extra

        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._sock = socket.socket(family, socket.SOCK_STREAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._sock.bind((host, port))
        except OSError as exc:
            self._sock.close()
            raise ConsoleUnavailable(
                f"web console: cannot listen on {host}:{port} ({exc.strerror}); set "
                "[humans.web] host and port") from None
        self._sock.listen(64)
        self.host = host
        self.port = int(self._sock.getsockname()[1])
        self.tls = certfile is not None
        config = uvicorn.Config(
            app, log_level="warning", access_log=False, lifespan="off", ws="websockets-sansio",
            ssl_certfile=certfile, ssl_keyfile=keyfile, timeout_graceful_shutdown=2,
            ws_ping_interval=PING_S, ws_ping_timeout=PING_S,
        )
        self._server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self._run, name="web-console", daemon=True)
        self._error: BaseException | None = None

    def _run(self) -> None:
        try:
            self._server.run(sockets=[self._sock])
        except BaseException as exc:  # reported by start()
            self._error = exc

    def start(self, timeout_s: float = 10.0) -> None:
        self._thread.start()
        deadline = time.monotonic() + timeout_s
        while not self._server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                raise ConsoleUnavailable(
                    f"web console: the server did not start ({self._error!r})")
            time.sleep(0.01)

    @property
    def base_url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{'https' if self.tls else 'http'}://{host}:{self.port}"

    def stop(self) -> None:
        self._server.should_exit = True
        self._thread.join(5.0)
        with contextlib.suppress(OSError):
            self._sock.close()
