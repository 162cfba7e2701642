"""Ctrl-C that never tears a record: the first one stops gracefully, the second at once.

The first SIGINT/SIGTERM raises ``KeyboardInterrupt`` in the main thread, so that a
loop blocked on a host or a human unwinds through its ``finally`` (arms to rest,
records closed) at once. But an interrupt raised in the middle of writing a step or a
checkpoint would tear it (torch.save, for one, turns it into a RuntimeError), so such
writes run inside ``critical()``: an interrupt arriving there is held until the block
ends. A watchdog keeps the promise of an exit within 5 s even if a host never answers
its rest command, and a second Ctrl-C exits immediately.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

EXIT_INTERRUPTED = 130
GRACE_S = 4.5


class _Interrupts:
    def __init__(self) -> None:
        self.count = 0
        self._depth = 0
        self._pending = False
        self._timer: threading.Timer | None = None

    def reset(self) -> None:
        """Forget an interrupt (and cancel its watchdog): for a host program that recovers."""
        if self._timer is not None:
            self._timer.cancel()
        self.count, self._pending, self._timer = 0, False, None

    def install(self) -> None:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, self._handler)
            signal.signal(signal.SIGTERM, self._handler)

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        self.count += 1
        if self.count > 1:
            os._exit(EXIT_INTERRUPTED)
        self._timer = threading.Timer(GRACE_S, os._exit, args=(EXIT_INTERRUPTED,))
        self._timer.daemon = True
        self._timer.start()
        if self._depth > 0:
            self._pending = True
            return
        raise KeyboardInterrupt

    @contextmanager
    def critical(self) -> Iterator[None]:
        """Hold an interrupt until the block's write is complete."""
        self._depth += 1
        try:
            yield
        finally:
            self._depth -= 1
            if self._depth == 0 and self._pending:
                self._pending = False
                raise KeyboardInterrupt


INTERRUPTS = _Interrupts()
critical = INTERRUPTS.critical
