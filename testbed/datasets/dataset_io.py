"""The verbs' entry points: ``export`` (``testbed export``) and ``load_frames``
(``testbed train --data``), each choosing the format.

Why apart: which formats exist, how a path names one, and that the LeRobot one is the
optional ``export`` extra (pyarrow, PyAV) are decided here and nowhere else. The npz
path needs numpy alone; ``testbed.datasets.lerobot`` is imported only on the LeRobot
path, after ``require_export_extra`` has said, in one line, what is missing.
"""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from testbed.core.config import ConfigError
from testbed.datasets.episodes import (
    Episode,
    Frames,
    gather,
    iter_episodes,
    of_sources,
    testbed_meta,
)
from testbed.datasets.npz import NPZ_NAME, npz_path, read_npz, write_npz
from testbed.datasets.sources import find_sources


def require_export_extra(video: bool) -> None:
    """pyarrow (and PyAV for video) are the optional ``export`` extra."""
    need = ["pyarrow", "av"] if video else ["pyarrow"]
    missing = [m for m in need if importlib.util.find_spec(m) is None]
    if missing:
        raise ConfigError(f"LeRobot datasets need {' and '.join(missing)} (the export "
                          'extra): pip install -e ".[export]"')


def load_frames(path: Path, flag: str = "--data") -> Frames:
    """A dataset to train on: an npz of ``testbed export`` (or a folder holding
    ``frames.npz``), a LeRobot dataset of ``testbed export``, or run/protocol folders."""
    frames = _read_export(path, flag)
    if frames is not None:
        for note in frames.notes:
            sys.stderr.write(f"testbed: {note}\n")
        return frames
    if path.is_dir():
        src = find_sources([path], flag)
        for note in src.notes:
            sys.stderr.write(f"testbed: {note}\n")
        return of_sources(src)
    raise ConfigError(f"{flag}: {str(path)!r} is neither an npz, a LeRobot dataset nor a "
                      "run folder of the testbed")


def _read_export(path: Path, flag: str) -> Frames | None:
    """An export of ``testbed export`` at ``path`` (npz or LeRobot), or None."""
    if path.is_file() and path.suffix == ".npz":
        return read_npz(path)
    if path.is_dir() and (path / NPZ_NAME).is_file():
        return read_npz(path / NPZ_NAME)
    if path.is_dir() and (path / "meta" / "info.json").is_file():
        video = (path / "videos").is_dir()
        require_export_extra(video)
        from testbed.datasets.lerobot import read_dataset

        return read_dataset(path, flag)
    return None


@dataclass
class ExportResult:
    """What ``export`` wrote (the verb's one line of output)."""

    path: Path
    frames: int
    episodes: int
    demo_episodes: int
    runs: int
    notes: list[str]


def export(dirs: Sequence[Path], fmt: str, out: Path, images: str = "png",
           note: Callable[[str], None] | None = None, **options: Any) -> ExportResult:
    """``testbed export``: the runs in ``dirs`` as ``fmt`` ("lerobot" or "npz") at
    ``out``. ``options`` go to the LeRobot writer (file sizes, tests)."""
    if fmt == "lerobot":
        require_export_extra(images == "video")
    src = find_sources(dirs)
    for line in src.notes:
        (note or (lambda s: sys.stderr.write(f"testbed export: {s}\n")))(line)
    demo_eps = 0

    def counted() -> Iterator[Episode]:
        nonlocal demo_eps
        for ep in iter_episodes(src):
            demo_eps += ep.source_index >= len(src.runs)
            yield ep

    meta = testbed_meta(src)
    if fmt == "npz":
        frames = gather(counted())
        path = npz_path(out)
        write_npz(frames, meta, path)
        n_frames = len(frames)
        n_eps = int(frames.columns["episode_index"].max(initial=-1)) + 1
    else:
        from testbed.datasets.lerobot import write_dataset

        path = out
        n_frames, n_eps = write_dataset(counted(), out, images, meta, **options)
    return ExportResult(path, n_frames, n_eps, demo_eps, len(src.runs), src.notes)
