"""Crash-safe checkpoint files: a torch-serialised dict, written atomically.

Why: a trial that dies mid-write (Ctrl-C twice, power, OOM) must leave either the old
checkpoint or the new one, never a torn file that ``--resume`` chokes on. So: write a
temp file in the same folder, fsync it, ``os.replace`` it over the target (atomic on
POSIX within one file system), then fsync the folder so the rename itself is durable.
Loading uses ``weights_only=True``: a checkpoint is data (tensors, numbers, strings,
lists, dicts) and loading one never runs pickled code.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Any

import torch

FORMAT = "testbed.learning.Learner/1"


def save_atomic(state: dict[str, Any], path: str | os.PathLike[str]) -> Path:
    """Write ``state`` to ``path`` atomically; returns the path."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(state, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    _fsync_dir(target.parent)
    return target


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # e.g. a platform without directory fds
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def load(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a checkpoint written by ``save_atomic`` (tensors on the CPU)."""
    state = torch.load(Path(path), map_location="cpu", weights_only=True)
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise ValueError(f"{path}: not a learner checkpoint (expected format {FORMAT})")
    return state
