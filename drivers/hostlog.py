"""Per-host log files: everything a host's agent said and everything we saw of it.

Why: when a host misbehaves during a trial, the operator needs one file per host that
holds the agent's own words (every stderr line: its lifecycle, backend warnings,
tracebacks) interleaved with the controller's view of the same host (started, connected
with which pid, dropped and why, reconnect attempts, faults), each line timestamped on
arrival. The transport only keeps a short tail of stderr for Fault messages; this keeps
all of it, in ``log_dir/<host>.log``, rotated (5 MB x 3) so a week-long run cannot fill
the disk.
"""

from __future__ import annotations

import logging
from logging.handlers import RotatingFileHandler
from pathlib import Path

MAX_BYTES = 5 * 1024 * 1024
BACKUPS = 3


class HostLog:
    """One host's log file. Thread-safe (logging's handler lock); never raises."""

    def __init__(self, log_dir: Path, host: str) -> None:
        log_dir.mkdir(parents=True, exist_ok=True)
        self.path = log_dir / f"{host}.log"
        # A Logger of our own, not registered in logging's manager: no propagation to
        # the root logger's handlers and nothing left behind when the fleet is gone.
        self._logger = logging.Logger(f"fleet.host.{host}", logging.INFO)
        self._handler = RotatingFileHandler(self.path, maxBytes=MAX_BYTES,
                                            backupCount=BACKUPS, encoding="utf-8")
        self._handler.setFormatter(logging.Formatter(
            "%(asctime)s.%(msecs)03d %(message)s", "%Y-%m-%d %H:%M:%S"))
        self._logger.addHandler(self._handler)

    def event(self, msg: str, *args: object) -> None:
        """The controller's own event about this host."""
        self._logger.info("fleet | " + msg, *args)

    def agent_line(self, line: str) -> None:
        """One line the agent wrote to its stderr."""
        self._logger.info("agent | %s", line)

    def close(self) -> None:
        self._handler.close()
        self._logger.removeHandler(self._handler)
