"""Crash-safe replacement of a file: a reader sees the old file or the new, never half.

Why in ``core``: every room that keeps something on disk (run records, checkpoints,
calibration files, datasets' metadata) replaces files the same way: a temp file in the
same folder, fsync, ``os.replace``, fsync the folder. The stdlib and numpy only.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["atomic_write_bytes", "atomic_write_json", "fsync_dir", "json_default"]


def fsync_dir(path: Path) -> None:
    # Makes a create/rename in the folder durable; not every platform can open one.
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Replace ``path`` with ``data`` atomically: temp in the same folder, fsync, replace."""
    target = Path(path)
    folder = target.parent
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp_name, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp_name)
        raise
    fsync_dir(folder)


def atomic_write_json(path: str | os.PathLike[str], obj: Any) -> None:
    """Atomically write ``obj`` as indented JSON (NaN/inf refused: they are not JSON)."""
    text = json.dumps(obj, indent=2, allow_nan=False, default=json_default) + "\n"
    atomic_write_bytes(path, text.encode("utf-8"))


def json_default(obj: object) -> Any:
    """numpy scalars and arrays as JSON (``json.dumps(default=...)``)."""
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")
