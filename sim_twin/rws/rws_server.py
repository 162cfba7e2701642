"""The RWS twin's HTTP server: stdlib ``ThreadingHTTPServer`` around an
:class:`~sim_twin.rws.rws_service.RwsService`, on loopback only.

Why it exists: the ABB clients speak HTTP/1.1 with keep-alive (``requests.Session``) and
digest authentication; this server gives every connection a thread, reads every body
(also of a request answered ``401``, so the connection stays usable for the client's
authenticated retry) and writes the service's answer with a ``Content-Length``.
Connections still open when the server stops are shut down, so a test that leaks
clients does not leave threads behind. ``request_log`` (optional, e.g.
:class:`~sim_twin.rws.request_log.RequestLog`) is told every request served: method, the
path with its query, the status and the milliseconds from its headers read to its
answer written.
"""

from __future__ import annotations

import contextlib
import ipaddress
import socket
import threading
import time
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from sim_twin.rws.rws_service import HttpReply, RwsService

MAX_BODY_BYTES = 64 << 20
RequestHook = Callable[[str, str, int, float], None]
"""(method, path with query, status, ms): told once per request served."""


def check_loopback(host: str) -> None:
    """``ValueError`` unless ``host`` is a loopback address (the twin never faces a LAN)."""
    if host == "localhost":
        return
    try:
        ok = ipaddress.ip_address(host).is_loopback
    except ValueError:
        ok = False
    if not ok:
        raise ValueError(f"the RWS twin listens on loopback only, not {host!r}")


class RwsServer(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, service: RwsService, host: str = "127.0.0.1", port: int = 0, *,
                 verbose: bool = False, request_log: RequestHook | None = None) -> None:
        check_loopback(host)
        self.service = service
        self.verbose = verbose
        self.request_log = request_log
        self._open: set[socket.socket] = set()
        self._open_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        super().__init__((host, port), _Handler)

    @property
    def port(self) -> int:
        return int(self.server_address[1])

    @property
    def url(self) -> str:
        """The base URL the ABB clients take (``http://127.0.0.1:PORT``)."""
        host = self.server_address[0]
        return f"http://{host}:{self.port}"

    def track(self, sock: socket.socket, on: bool) -> None:
        with self._open_lock:
            (self._open.add if on else self._open.discard)(sock)

    def start_thread(self) -> RwsServer:
        """Serve in a daemon thread; returns self (``server.url``, ``server.stop()``)."""
        self._thread = threading.Thread(target=self.serve_forever, kwargs={"poll_interval": 0.1},
                                        daemon=True, name=f"rws-twin-{self.port}")
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving, close open connections and the listening socket."""
        if self._thread is not None:
            self.shutdown()
            self._thread.join(5.0)
            self._thread = None
        with self._open_lock:
            for s in list(self._open):
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)
        self.server_close()


class _Handler(BaseHTTPRequestHandler):
    server: RwsServer
    protocol_version = "HTTP/1.1"
    server_version = "RWS-twin/1.0"
    timeout = 120

    def setup(self) -> None:
        super().setup()
        # Headers and body go out in two writes; without this, Nagle's algorithm and the
        # client's delayed ACK add ~40 ms to every answer.
        self.connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.server.track(self.connection, True)

    def finish(self) -> None:
        self.server.track(self.connection, False)
        with contextlib.suppress(OSError):
            super().finish()

    def log_message(self, format: str, *args: Any) -> None:
        if self.server.verbose:
            super().log_message(format, *args)

    def _body(self) -> bytes | None:
        if "chunked" in self.headers.get("Transfer-Encoding", "").lower():
            return None
        n = int(self.headers.get("Content-Length") or 0)
        if n > MAX_BODY_BYTES:
            return None
        return self.rfile.read(n) if n > 0 else b""

    def _serve(self) -> None:
        start = time.perf_counter()
        body = self._body()
        if body is None:
            reply = HttpReply(411 if "chunked" in self.headers.get("Transfer-Encoding", "")
                              else 413, [("Content-Type", "text/plain")],
                              b"the twin needs a Content-Length of at most 64 MiB")
            self.close_connection = True
        else:
            host = self.headers.get("Host") or f"127.0.0.1:{self.server.port}"
            reply = self.server.service.handle(self.command, self.path, self.headers.items(),
                                               body, f"http://{host}")
        try:
            self._write(reply)
        finally:
            hook = self.server.request_log
            if hook is not None:
                hook(self.command, self.path, reply.status,
                     (time.perf_counter() - start) * 1000.0)

    def _write(self, reply: HttpReply) -> None:
        self.send_response(reply.status)
        for k, v in reply.headers:
            self.send_header(k, v)
        self.send_header("Content-Length", str(len(reply.body)))
        self.end_headers()
        if reply.body and self.command != "HEAD":
            self.wfile.write(reply.body)

    do_GET = do_POST = do_PUT = do_DELETE = _serve
