"""The controller's event log (elog): numbered entries, newest first, as RWS serves them.

Why it exists: ``abb_motion_program_exec`` reads the event log before a program starts
(the newest sequence number) and after it ends (every entry past that number): an entry
of type 3 (error) means the program failed, and the ``80003`` entries the RAPID module
writes name the joint log file. So the twin must keep a real log: sequence numbers that
only grow, entries newest first, a code, a type, a time stamp, arguments and the texts.

The domain of an entry is its code's ten-thousands digit (1xxxx operational,
4xxxx program/RAPID, 8xxxx user's ErrWrite, ...); domain 0 ("common") lists them all,
as RWS's ``rw/elog/0`` does. The buffer keeps the newest ``capacity`` entries (1000,
as the manual's example domain 0 shows; its domain 1 holds 20): a long day rolls the
oldest out, and tests play that with a small :attr:`EventLog.capacity`. Clearing is RWS's
"Clear elog messages" (``POST rw/elog?action=clearall``, every domain; ``POST
rw/elog/{domain}?action=clear``, one), served by ``sim_twin/rws/resources.py``.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

MSG_INFO, MSG_WARNING, MSG_ERROR = 1, 2, 3
TSTAMP_FORMAT = "%Y-%m-%d T %H:%M:%S"
"""RWS's time stamp (``2013-09-08 T 11:22:10``, controller clock)."""


@dataclass(frozen=True)
class ElogEntry:
    """One event log message."""

    seqnum: int
    code: int
    msgtype: int
    title: str
    desc: str = ""
    conseqs: str = ""
    causes: str = ""
    actions: str = ""
    args: tuple[str, ...] = ()
    src_name: str = "RAPID"
    wall_time: float = field(default_factory=time.time)

    @property
    def domain(self) -> int:
        return self.code // 10000

    @property
    def tstamp(self) -> str:
        return time.strftime(TSTAMP_FORMAT, time.localtime(self.wall_time))


class EventLog:
    """Thread-safe; ``write`` from any thread (the request handlers, the program run)."""

    def __init__(self, capacity: int = 1000, first_seqnum: int = 1) -> None:
        self._lock = threading.Lock()
        self._entries: deque[ElogEntry] = deque(maxlen=capacity)
        self._next = int(first_seqnum)

    def write(self, code: int, msgtype: int, title: str, *, desc: str = "",
              conseqs: str = "", causes: str = "", actions: str = "",
              args: Sequence[object] = (), src_name: str = "RAPID") -> ElogEntry:
        """Append an entry and return it (its ``seqnum`` is the next number)."""
        if msgtype not in (MSG_INFO, MSG_WARNING, MSG_ERROR):
            raise ValueError(f"msgtype must be 1 (info), 2 (warning) or 3 (error), "
                             f"got {msgtype!r}")
        with self._lock:
            entry = ElogEntry(self._next, int(code), msgtype, title, desc, conseqs, causes,
                              actions, tuple(str(a) for a in args), src_name)
            self._next = self._next + 1 if self._next < 0xFFFF else 0  # RW's uint16
            self._entries.append(entry)
            return entry

    def entries(self, domain: int = 0) -> list[ElogEntry]:
        """Newest first; domain 0 is every entry."""
        with self._lock:
            items = list(self._entries)
        items.reverse()
        return items if domain == 0 else [e for e in items if e.domain == domain]

    def get(self, seqnum: int) -> ElogEntry | None:
        with self._lock:
            return next((e for e in self._entries if e.seqnum == seqnum), None)

    def clear(self, domain: int = 0) -> None:
        with self._lock:
            keep = [e for e in self._entries if domain != 0 and e.domain != domain]
            self._entries.clear()
            self._entries.extend(keep)

    @property
    def capacity(self) -> int:
        """How many entries the log keeps (the newest)."""
        return int(self._entries.maxlen or 0)

    @capacity.setter
    def capacity(self, n: int) -> None:
        """Keep at most ``n`` entries from now on (the oldest beyond ``n`` drop out)."""
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"capacity must be a positive int, got {n!r}")
        with self._lock:
            self._entries = deque(self._entries, maxlen=n)

    @property
    def newest(self) -> int | None:
        with self._lock:
            return self._entries[-1].seqnum if self._entries else None
