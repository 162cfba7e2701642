"""The agent's watchdog, and the one way it stops a backend.

Why apart from the session: stopping a motion is the agent's safety rule, and it has
three callers (the controller's ``stop``, the controller gone, and the watchdog: a
request runs and no frame at all has come from the controller for ``--watchdog``
seconds, so the link stopped answering and nobody watches the robot). One function
stops, times and never raises; one small class decides when the silence is due, once
per request.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from drivers.backends.base import HostBackend

__all__ = ["STOP_LIMIT_S", "Watchdog", "stop_backend"]

log = logging.getLogger("drivers.agent")

STOP_LIMIT_S = 0.5
"""``HostBackend.stop`` returns within this (the reader hears nothing meanwhile)."""


class Watchdog:
    """Silence from the controller while a request runs: due once per request."""

    def __init__(self, after_s: float | None) -> None:
        self.after_s = after_s
        self._watched = 0  # the request the watchdog last stopped

    def due(self, silent_s: float, current: str | None, seq: int) -> bool:
        """True (once for request number ``seq``) when ``current`` runs and the
        controller has said nothing for ``after_s``; says so in the log."""
        if self.after_s is None or current is None or seq == self._watched \
                or silent_s < self.after_s:
            return False
        self._watched = seq
        log.error("watchdog: no frame from the controller for %.1f s during %s; stopping "
                  "the motion (the link stopped answering, nobody watches the robot)",
                  silent_s, current)
        return True


def stop_backend(backend: HostBackend | None, why: str, current: str | None) -> None:
    """``backend.stop()``, timed, never raising (the reader must go on)."""
    if backend is None:
        return
    t0 = time.monotonic()
    try:
        backend.stop()
    except Exception:  # say it; the caller goes on as if stopped
        log.exception("stopping the backend (%s) failed", why)
        return
    took = time.monotonic() - t0
    log.log(logging.WARNING if took > STOP_LIMIT_S else logging.INFO,
            "stopped the backend (%s) during %s in %.3f s%s", why, current or "no request",
            took, " (HostBackend.stop must return within 0.5 s)" if took > STOP_LIMIT_S else "")
