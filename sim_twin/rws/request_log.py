"""The RWS twin's request log: one JSON line per request served, for the rehearsal's
record of what the agent asked the controller.

Why it exists: a rehearsal must show how the driver uses the controller (how many calls a
step makes, how long they take, which ones fail) without a packet capture; and a twin
that crashed must still leave what it served. So every request is one line, written and
flushed as its answer goes out: ``{"t": unix time, "method", "path" (with the query
string), "status", "ms"}``. Never a header, a cookie or a body: the log holds no
credentials and no session.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from types import TracebackType

__all__ = ["RequestLog"]


class RequestLog:
    """Appends to ``path`` (created with its folder); thread-safe; call :meth:`close`."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._file = path.open("a", encoding="utf-8")

    def __call__(self, method: str, path: str, status: int, ms: float) -> None:
        """One request served: ``path`` as the request line had it (the query included)."""
        line = json.dumps({"t": round(time.time(), 6), "method": method, "path": path,
                           "status": int(status), "ms": round(ms, 3)})
        with self._lock:
            if self._file.closed:
                return
            self._file.write(line + "\n")
            self._file.flush()

    def close(self) -> None:
        with self._lock:
            self._file.close()

    def __enter__(self) -> RequestLog:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
