"""The per-robot lock on a robot host: one agent drives a robot, a second is refused.

Why: two controllers (two operators, or a stale trial and a new one) could each start an
agent for the same YuMi; both would send motion programs to one controller and the arms
would move for two masters. So before it builds its backend (before it touches the
camera or the controller), an agent takes an exclusive ``fcntl.flock`` on a lock file
named after the robot, and writes who it is into it. A second agent for the same robot
fails its start with a message naming the holder, and never builds the backend. The
kernel releases the lock when the holder exits, however it exits, so a stale file is
never a stale lock.

Identity: for a YuMi the controller URL (normalised: scheme and host lower-case, default
port explicit, trailing slash dropped), since that is the thing that moves; a twin agent
owns its own simulated cell, so it is locked only when given an explicit ``--lock-id``.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import re
import socket
import time
from pathlib import Path
from urllib.parse import urlsplit

DEFAULT_PORTS = {"http": 80, "https": 443}


class RobotBusy(RuntimeError):
    """Another live agent holds this robot's lock."""


def default_lock_dir() -> str:
    return os.path.join(os.environ.get("XDG_RUNTIME_DIR") or "/tmp", "fleet-testbed-locks")


def normalise_url(url: str) -> str:
    """A controller URL in one spelling per robot (``HTTP://Host:80/`` ==
    ``http://host``)."""
    parts = urlsplit(url.strip())
    scheme = parts.scheme.lower()
    host = (parts.hostname or "").lower()
    if not scheme or not host:
        return url.strip()
    try:
        port = parts.port or DEFAULT_PORTS.get(scheme)
    except ValueError:  # a malformed port: the URL as written is the identity
        return url.strip()
    if ":" in host:
        host = f"[{host}]"
    path = parts.path.rstrip("/")
    return f"{scheme}://{host}{f':{port}' if port else ''}{path}"


def lock_identity(backend: str, controller_url: str | None, lock_id: str | None) -> str | None:
    """What this agent must own exclusively, or None (an unlocked twin agent)."""
    if lock_id:
        return lock_id
    if backend == "yumi" and controller_url:
        return normalise_url(controller_url)
    return None


def lock_path(lock_dir: str | os.PathLike[str], identity: str) -> Path:
    slug = re.sub(r"[^A-Za-z0-9._-]+", "_", identity).strip("_")[:60] or "robot"
    digest = hashlib.sha256(identity.encode()).hexdigest()[:12]
    return Path(lock_dir) / f"{slug}-{digest}.lock"


def describe_holder(identity: str, raw: str, path: Path) -> str:
    """The refusal, one line: which agent holds the robot, since when, from where."""
    try:
        h = json.loads(raw)
        if not isinstance(h, dict):
            raise ValueError
    except ValueError:
        who = "another agent (it has not written its details yet)"
    else:
        who = f"agent pid {h.get('pid', '?')} on host {h.get('host', '?')}"
        if h.get("started"):
            who += f" since {h['started']}"
        where = [f"from {h['ssh_connection']}"] if h.get("ssh_connection") else []
        if h.get("machine") and h.get("machine") != h.get("host"):
            where.append(f"machine {h['machine']}")
        if where:
            who += f" ({'; '.join(where)})"
    return (f"robot {identity} is held by {who}; only one agent may drive a robot: stop "
            f"that agent (or the controller that started it) first; lock file {path}")


class RobotLock:
    """An exclusive flock held for the agent's lifetime (released on :meth:`release` or
    by the kernel at exit)."""

    def __init__(self, identity: str, lock_dir: str | os.PathLike[str], host: str) -> None:
        self.identity = identity
        self.path = lock_path(lock_dir, identity)
        self._fd: int | None = None
        self._host = host

    def acquire(self) -> None:
        """Take the lock or raise :class:`RobotBusy` naming the holder (OSError if the
        lock directory is unusable)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raw = os.pread(fd, 65536, 0).decode("utf-8", "replace")
            os.close(fd)
            raise RobotBusy(describe_holder(self.identity, raw, self.path)) from None
        except BaseException:
            os.close(fd)
            raise
        ssh = os.environ.get("SSH_CONNECTION", "").split()
        holder = {"pid": os.getpid(), "host": self._host, "machine": socket.gethostname(),
                  "started": time.strftime("%H:%M:%S"),
                  "started_iso": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                  "ssh_connection": " ".join(ssh[:2]) if ssh else None,
                  "robot": self.identity}
        data = json.dumps(holder).encode()
        os.ftruncate(fd, 0)
        os.pwrite(fd, data, 0)
        os.fsync(fd)
        self._fd = fd

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)  # no stale holder details for the next reader
            with contextlib.suppress(OSError):
                fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)

    @property
    def held(self) -> bool:
        return self._fd is not None
