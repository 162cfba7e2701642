"""The agent's two file descriptors: frames out on the real stdout, frames in on stdin.

Why: stdout carries ONLY frames. The agent duplicates fd 1 for its frames and points
fd 1 (and ``sys.stdout``) at stderr before anything else is imported, because pybullet
prints its build time to fd 1 at import and a stray ``print`` would corrupt the stream.
Both descriptors are non-blocking, with deadlines, so a dead controller never hangs it.
"""

from __future__ import annotations

import os
import select
import sys
import time
from collections.abc import Callable

from drivers.errors import DeadlineExceeded

__all__ = ["claim_stdout", "fd_reader", "fd_writer"]


def claim_stdout() -> int:
    """Keep fd 1 for frames (returned dup) and send everything else printed to stderr."""
    frames_fd = os.dup(1)
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    return frames_fd


def fd_reader(fd: int) -> Callable[[int, float], bytes]:
    """``read(n, deadline)`` on ``fd``, non-blocking: DeadlineExceeded past the deadline,
    so the session's idle timeout and watchdog run even when no byte comes."""
    os.set_blocking(fd, False)

    def read(n: int, deadline: float) -> bytes:
        while True:
            try:
                return os.read(fd, n)  # a pipelined request is often there already
            except BlockingIOError:
                pass
            timeout = deadline - time.monotonic()
            if timeout <= 0:
                raise DeadlineExceeded("no frame from the controller in time")
            select.select([fd], [], [], timeout)

    return read


def fd_writer(fd: int, timeout_s: float) -> Callable[[bytes], None]:
    """``write(data)`` on ``fd``, whole or BrokenPipeError after ``timeout_s``: a
    controller that stopped reading must not hang the agent (it then stops the arms)."""
    os.set_blocking(fd, False)

    def write(data: bytes) -> None:
        view = memoryview(data)
        deadline = time.monotonic() + timeout_s
        while view:
            try:
                n = os.write(fd, view)
            except BlockingIOError:
                n = 0
            view = view[n:]
            if view:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise BrokenPipeError("the controller stopped reading our replies")
                select.select([], [fd], [], left)

    return write
