"""The per-robot lock on a robot host: one agent drives a robot, a second is refused.

Why: two controllers (two operators, or a stale trial and a new one) could each start an
agent for the same YuMi; both would send motion programs to one controller and the arms
would move for two masters. So before it builds its backend (before it touches the
camera or the controller), an agent takes an exclusive ``fcntl.flock`` on a lock file
named after the robot, and writes who it is into it. A second agent for the same robot
fails its start with a message naming the holder, and never builds the backend. The
kernel releases the lock when the holder exits, however it exits, so a stale file is
never a stale lock.

Identity: for a YuMi the robot as its controller reports itself (its serial, from the
read-only ``ctrl/identity`` and ``rw/system`` queries the agent makes before the lock:
``drivers.yumi.rws_controller.controller_info``, which its hello also carries), so two
spellings of one controller's address are one robot; when the controller cannot be
asked, the controller URL (normalised: scheme and host lower-case, default port
explicit, trailing slash dropped). A twin agent owns its own simulated cell, so it is
locked only when given an explicit ``--lock-id``.

For every user: the lock directory is one per host, shared by all its users (default
:func:`default_lock_dir`, ``/run/lock/fleet-testbed``: the system's directory for lock
files, world-writable and sticky; ``--lock-dir`` or the host config's ``lock_dir``
otherwise), and each lock file is readable and writable by all (0666), so a colleague's
agent for the same robot, under another Unix user, is refused as one's own is. The file
names its holder: user, pid, host, controller address, since when.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import pwd
import re
import socket
import time
from pathlib import Path
from urllib.parse import urlsplit

DEFAULT_PORTS = {"http": 80, "https": 443}


class RobotBusy(RuntimeError):
    """Another live agent holds this robot's lock."""


SHARED_LOCK_ROOTS = ("/run/lock", "/var/lock", "/tmp")
"""Where the shared lock folder goes: the first of these that exists (Debian's /run/lock
is the system's, mode 1777)."""


def default_lock_dir() -> str:
    """One folder per host for every user's agents (not ``$XDG_RUNTIME_DIR``, which is
    per user: a colleague's agent would not see the lock)."""
    root = next((r for r in SHARED_LOCK_ROOTS if os.path.isdir(r)), "/tmp")
    return os.path.join(root, "fleet-testbed")


def _shared_dir(path: Path) -> None:
    """Create the lock folder sticky and world-writable (as /tmp): every user may add a
    lock file, nobody may remove another's."""
    if path.is_dir():
        return
    path.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(OSError):  # someone else's folder: theirs to set
        os.chmod(path, 0o1777)


def _open_shared(path: Path) -> int:
    """The lock file, read-write, made 0666 when we create it. Opened WITHOUT ``O_CREAT``
    when it exists: Linux's ``fs.protected_regular`` refuses an ``O_CREAT`` open of
    another user's file in a sticky world-writable folder, the very case of a colleague's
    lock."""
    flags = os.O_RDWR | os.O_CLOEXEC
    for _ in range(3):
        try:
            return os.open(path, flags)
        except FileNotFoundError:
            pass
        try:
            fd = os.open(path, flags | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:  # made by another agent just now: open theirs
            continue
        with contextlib.suppress(OSError):  # the umask took bits: every user may lock it
            os.fchmod(fd, 0o666)
        return fd
    return os.open(path, flags)


def _user() -> str:
    try:
        return pwd.getpwuid(os.geteuid()).pw_name
    except KeyError:
        return f"uid {os.geteuid()}"


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
        user = f" of user {h['user']}" if h.get("user") else ""
        who = f"agent pid {h.get('pid', '?')}{user} on host {h.get('host', '?')}"
        if h.get("started"):
            who += f" since {h['started']}"
        where = [f"controller {h['controller']}"] if h.get("controller") else []
        if h.get("ssh_connection"):
            where.append(f"from {h['ssh_connection']}")
        if h.get("machine") and h.get("machine") != h.get("host"):
            where.append(f"machine {h['machine']}")
        if where:
            who += f" ({'; '.join(where)})"
    return (f"robot {identity} is held by {who}; only one agent may drive a robot: stop "
            f"that agent (or the controller that started it) first; lock file {path}")


class RobotLock:
    """An exclusive flock held for the agent's lifetime (released on :meth:`release` or
    by the kernel at exit)."""

    def __init__(self, identity: str, lock_dir: str | os.PathLike[str], host: str, *,
                 controller: str | None = None) -> None:
        self.identity = identity
        self.path = lock_path(lock_dir, identity)
        self._fd: int | None = None
        self._host = host
        self._controller = controller

    def acquire(self) -> None:
        """Take the lock or raise :class:`RobotBusy` naming the holder (OSError if the
        lock directory is unusable)."""
        _shared_dir(self.path.parent)
        fd = _open_shared(self.path)
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
        holder = {"pid": os.getpid(), "user": _user(), "host": self._host,
                  "controller": self._controller, "machine": socket.gethostname(),
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
