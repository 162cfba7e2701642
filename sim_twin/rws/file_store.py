"""The controller's file system as RWS's ``/fileservice`` shows it: kept in memory.

Why it exists: ``abb_motion_program_exec`` uploads its motion program (a binary file) to
the controller's RAM disk, the RAPID module reads it from there, writes a joint log next
to it, and the client reads the log back and deletes it. The twin stores what is uploaded
so the later RAPID-semantics work can read the very bytes the library sent, and so the
library's read/list/delete calls answer as on a controller.

Paths: ``$VAR/rest`` (an environment variable, case-insensitive, as ``$home`` and
``$HOME`` both work on RWS), ``hd0a/...`` (an absolute device path) and, for the twin's
own Python API only, RAPID's device syntax ``RAMDISK:file``. ``..`` is refused. The
environment variables and their folders are constructor arguments; ``RAMDISK`` is the
folder RAPID's ``RAMDISK:`` device opens, and ``ramdisk_value`` is what ``ctrl/$RAMDISK``
answers (the path the library prefixes to its file names).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass

from sim_twin.rws.errors import GENERIC, RwsError, refused

DEFAULT_ENV = {"HOME": "hd0a/YUMI_TWIN/HOME", "TEMP": "hd0a/temp",
               "SYSTEM": "hd0a/YUMI_TWIN", "BACKUP": "hd0a/BACKUP",
               "RAMDISK": "hd0a/temp"}
DEFAULT_RAMDISK_VALUE = "$TEMP"
FS_TIME_FORMAT = "%Y-%m-%d T %H:%M:%S"
MAX_FILE_BYTES = 64 << 20


@dataclass
class FileEntry:
    data: bytes
    created: float
    modified: float


def _stamp(t: float) -> str:
    return time.strftime(FS_TIME_FORMAT, time.localtime(t))


class FileStore:
    """Folders and files, thread-safe. Canonical paths are ``device/dir/.../name``."""

    def __init__(self, env: Mapping[str, str] | None = None,
                 ramdisk_value: str = DEFAULT_RAMDISK_VALUE) -> None:
        self.env = {k.upper(): v.strip("/") for k, v in (env or DEFAULT_ENV).items()}
        self.ramdisk_value = ramdisk_value
        self._lock = threading.Lock()
        self._files: dict[str, FileEntry] = {}
        now = time.time()
        self._dirs: dict[str, float] = {}
        for folder in self.env.values():
            parts = folder.split("/")
            for i in range(1, len(parts) + 1):
                self._dirs.setdefault("/".join(parts[:i]), now)

    # --- paths ------------------------------------------------------------------------
    def resolve(self, path: str) -> str:
        """The canonical path of ``path`` (see the module docstring); ``RwsError`` 404 for
        an unknown variable, 400 for ``..``."""
        p = path.strip()
        if ":" in p.split("/", 1)[0] and not p.startswith("$"):
            device, _, rest = p.partition(":")
            p = f"${device}/{rest}"
        parts = [s for s in p.strip("/").split("/") if s not in ("", ".")]
        if any(s == ".." for s in parts):
            raise refused(400, GENERIC, f"'..' is not allowed in a path: {path!r}")
        if parts and parts[0].startswith("$"):
            var = parts[0][1:].upper()
            if var not in self.env:
                raise refused(404, GENERIC, f"no environment variable ${var}")
            parts = [*self.env[var].split("/"), *parts[1:]]
        return "/".join(parts)

    def env_value(self, name: str) -> str | None:
        """What ``ctrl/$NAME`` answers: ``ramdisk_value`` for RAMDISK, else the folder."""
        key = name.lstrip("$").upper()
        if key == "RAMDISK":
            return self.ramdisk_value
        folder = self.env.get(key)
        return None if folder is None else "/" + folder

    # --- files ------------------------------------------------------------------------
    def is_dir(self, path: str) -> bool:
        c = self.resolve(path)
        with self._lock:
            return c == "" or c in self._dirs

    def put(self, path: str, data: bytes) -> bool:
        """Write a file (its folder must exist). True if it was created, False if it
        replaced one."""
        c = self.resolve(path)
        if len(data) > MAX_FILE_BYTES:
            raise refused(413, GENERIC, f"file larger than {MAX_FILE_BYTES} bytes")
        parent = c.rpartition("/")[0]
        with self._lock:
            if c in self._dirs or not c:
                raise refused(400, GENERIC, f"{path!r} is a folder")
            if parent not in self._dirs:
                raise refused(404, GENERIC, f"no folder {parent!r} for {path!r}")
            now = time.time()
            old = self._files.get(c)
            self._files[c] = FileEntry(bytes(data), old.created if old else now, now)
            return old is None

    def read(self, path: str) -> bytes:
        c = self.resolve(path)
        with self._lock:
            entry = self._files.get(c)
        if entry is None:
            raise refused(404, GENERIC, f"no file {path!r}")
        return entry.data

    def exists(self, path: str) -> bool:
        try:
            c = self.resolve(path)
        except RwsError:
            return False
        with self._lock:
            return c in self._files

    def delete(self, path: str) -> None:
        c = self.resolve(path)
        with self._lock:
            if c in self._files:
                del self._files[c]
                return
            if c in self._dirs and not any(k.startswith(c + "/")
                                           for k in (*self._files, *self._dirs)):
                del self._dirs[c]
                return
        raise refused(404, GENERIC, f"no file {path!r} (or the folder is not empty)")

    def mkdir(self, path: str, name: str) -> None:
        base = self.resolve(path)
        new = self.resolve(f"{base}/{name}") if base else self.resolve(name)
        with self._lock:
            if base and base not in self._dirs:
                raise refused(404, GENERIC, f"no folder {path!r}")
            now = time.time()
            parts = new.split("/")
            for i in range(1, len(parts) + 1):
                self._dirs.setdefault("/".join(parts[:i]), now)

    def listdir(self, path: str) -> list[dict[str, str]]:
        """The folder's entries as RWS lists them (``fs-dir`` / ``fs-file``)."""
        c = self.resolve(path)
        prefix = c + "/" if c else ""
        with self._lock:
            if c and c not in self._dirs:
                raise refused(404, GENERIC, f"no folder {path!r}")
            dirs = sorted((k, t) for k, t in self._dirs.items()
                          if k.startswith(prefix) and "/" not in k[len(prefix):] and k != c)
            files = sorted((k, e) for k, e in self._files.items()
                           if k.startswith(prefix) and "/" not in k[len(prefix):])
        out = [{"_type": "fs-dir", "_title": k[len(prefix):], "fs-cdate": _stamp(t),
                "fs-mdate": _stamp(t)} for k, t in dirs]
        out += [{"_type": "fs-file", "_title": k[len(prefix):], "fs-cdate": _stamp(e.created),
                 "fs-mdate": _stamp(e.modified), "fs-size": str(len(e.data)),
                 "fs-readonly": "false"} for k, e in files]
        return out
