"""``--format npz``: a whole dataset as one compressed npz that numpy alone reads.

Why apart: the npz is the format for code that wants no pyarrow, no PyAV and no LeRobot
-- ``np.load`` gives every column, the raw uint8 images, the tasks and the codes. Its
layout changes with this module alone; the episode model is ``testbed.datasets.episodes``.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any, Final

import numpy as np

from testbed.core.config import ConfigError
from testbed.datasets.episodes import COLUMNS, ESSENTIAL, INDEX_COLUMNS, Frames, read_back

NPZ_NAME: Final = "frames.npz"


def npz_path(out: Path) -> Path:
    """``--out`` of ``--format npz``: a file ending .npz, else a folder holding
    ``frames.npz``."""
    return out if out.suffix == ".npz" else out / NPZ_NAME


def write_npz(frames: Frames, meta: dict[str, Any], path: Path) -> None:
    """One compressed npz (temp file, then renamed): every column, ``image``, the
    tasks and the codes (``meta``, JSON text); loads with ``np.load`` alone."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez_compressed(f, image=frames.images, **frames.columns,
                                tasks=np.asarray(frames.tasks, dtype=str),
                                meta=np.asarray(json.dumps(meta)))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def read_npz(path: Path) -> Frames:
    """An npz of ``write_npz`` back in memory; ConfigError if it is not one. One of an
    older layout is completed (``read_back``: columns filled or derived, a note each)."""
    with np.load(path) as z:
        names = [n for n, _, _ in COLUMNS] + [n for n, _ in INDEX_COLUMNS]
        missing = [n for n in ("image", "tasks", *ESSENTIAL, *(n for n, _ in INDEX_COLUMNS))
                   if n not in z.files]
        if missing:
            raise ConfigError(f"--data: {path} is not an npz of testbed export (missing "
                              f"{', '.join(sorted(missing)[:3])})")
        meta = json.loads(str(z["meta"])) if "meta" in z.files else {}
        frames = Frames({n: z[n] for n in names if n in z.files}, z["image"],
                        [str(t) for t in z["tasks"]])
    return read_back(frames, meta if isinstance(meta, dict) else {}, str(path))
