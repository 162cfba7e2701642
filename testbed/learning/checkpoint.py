"""Crash-safe checkpoint files: a torch-serialised dict, written atomically.

Why: a trial that dies mid-write (Ctrl-C twice, power, OOM) must leave either the old
checkpoint or the new one, never a torn file that ``--resume`` chokes on. So: write a
temp file in the same folder, fsync it, ``os.replace`` it over the target (atomic on
POSIX within one file system), then fsync the folder so the rename itself is durable.
Loading uses ``weights_only=True``: a checkpoint is data (tensors, numbers, strings,
lists, dicts) and loading one never runs pickled code.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Any

import torch

from testbed.core.atomic import atomic_write_bytes

FORMAT = "testbed.learning.Learner/1"
"""A whole learner: weights, optimisers, sampler, counters and data."""
TRAINING_FORMAT = "testbed.learning.Learner.training/1"
"""A trial's per-step checkpoint: the same without the data (``Learner.training_state``)."""


def save_atomic(state: dict[str, Any], path: str | os.PathLike[str]) -> Path:
    """Write ``state`` to ``path`` atomically (the run records' writer); returns the path."""
    buf = io.BytesIO()
    torch.save(state, buf)
    atomic_write_bytes(path, buf.getvalue())
    return Path(path)


def load_any(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A checkpoint of either format (its ``format`` key says which)."""
    state = torch.load(Path(path), map_location="cpu", weights_only=True)
    if not isinstance(state, dict) or state.get("format") not in (FORMAT, TRAINING_FORMAT):
        raise ValueError(f"{path}: not a learner checkpoint")
    return state


def load(path: str | os.PathLike[str], kind: str = FORMAT) -> dict[str, Any]:
    """Read a checkpoint written by ``save_atomic`` (tensors on the CPU) of format
    ``kind`` (``FORMAT`` or ``TRAINING_FORMAT``)."""
    state = torch.load(Path(path), map_location="cpu", weights_only=True)
    if not isinstance(state, dict) or state.get("format") != kind:
        raise ValueError(f"{path}: not a learner checkpoint (expected format {kind})")
    return state
