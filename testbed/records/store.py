"""The run's data: every arm's frame of every step, on disk beside steps.jsonl.

Why: every human label costs a person's time, so a run keeps all it saw (issue 14),
and the per-step checkpoint holds weights and counters only: resume rebuilds the
learner's data by replaying this store (:func:`replay`), instead of every step
rewriting the whole replay data into the checkpoint (75 MB a step at the end of a
250-step trial before).

Layout of ``runs/<name>/data/``::

    meta.json            format, robots, steps per chunk, the frame's numpy dtype
    frames-00000.bin     fixed-size records, one per arm per step, steps 0..S-1
    frames-00001.bin     steps S..2S-1, ...

A frame (``FRAME_DTYPE``): the step ``t``, the arm's index, the process ``session``
(0, then +1 at every resume), whether the arm was ``observed`` (else it faulted and
its image is zeros), its ``mode`` (index into ``MODES``: who acted), the ``human``
(-1: none), the pushed ``action`` (-1: none), ``success``, ``violation``,
``uncertainty`` and ``risk`` (NaN when faulted), the ``goal`` (canonical x, y; NaN
when not observed), the ``wall_time`` (seconds since the epoch) and the 64x64 RGB
``image``.

Why fixed-size records in raw files, appended: a step is one ``write`` + ``fsync``
(1.2 MB at 100 arms), nothing on disk is ever rewritten, and a crash can only tear
the last record, which readers drop (a step counts once all its arms' frames are
there). numpy reads a chunk with no copy (``np.memmap(path, dtype)``) and no torch;
the dtype is in ``meta.json`` for any other reader. Parquet, HDF5 and zarr all
rewrite a footer or metadata on append, so a crash mid-write can cost the whole
file (HDF5) or needs the same recovery rules anyway. Chunks keep files ~128 MB.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Final, Protocol

import numpy as np

from testbed.core.atomic import atomic_write_json, fsync_dir
from testbed.core.types import IMAGE_SIZE, Mode
from testbed.records.frame_classes import LabelFeed

FORMAT_FAMILY: Final = "testbed.rundata/"
FORMAT_VERSION: Final = 1
"""The frame layout's version: bumped with every change of ``FRAME_DTYPE`` (a test pins
each version's layout). Data of an older version stays readable (its dtype is in its
meta.json); only this version's data is appended to (a resume)."""
FORMAT: Final = f"{FORMAT_FAMILY}{FORMAT_VERSION}"
FOLDER: Final = "data"
META: Final = "meta.json"
MODES: Final[tuple[str, ...]] = tuple(m.value for m in Mode)
"""``mode`` codes: autonomous (the policy acted), teleop and reset (a human acted),
idle (waiting for a hard reset), fault, refused."""

FRAME_DTYPE: Final = np.dtype([
    ("t", "<i4"),
    ("arm", "<i2"),
    ("session", "<i2"),
    ("observed", "?"),
    ("mode", "i1"),
    ("human", "i1"),
    ("action", "i1"),
    ("success", "?"),
    ("violation", "?"),
    ("uncertainty", "<f4"),
    ("risk", "<f4"),
    ("goal", "<f4", (2,)),
    ("wall_time", "<f8"),
    ("image", "u1", (IMAGE_SIZE, IMAGE_SIZE, 3)),
])
FRAME_READINGS: Final[tuple[str, ...]] = ()
"""The robot host's readings (``ArmStep.readings``, by name) that are also frame columns:
each a ``<f4`` field of ``FRAME_DTYPE`` under the same name, NaN where the host did not
measure it. Why a list here: ``StepRecord.to_frames`` fills every name of it, so a
reading made a column is this line, its field and a new ``FORMAT_VERSION``, in this
file alone (the exports take the field as they take every other)."""
CHUNK_BYTES: Final = 128 * 2**20

_AUTONOMOUS: Final = MODES.index(Mode.AUTONOMOUS.value)
_TELEOP: Final = MODES.index(Mode.TELEOP.value)


class RunDataError(ValueError):
    """A data folder that is not this format, or does not match the run."""


def steps_per_chunk(num_robots: int) -> int:
    return max(1, CHUNK_BYTES // (FRAME_DTYPE.itemsize * max(num_robots, 1)))


def _chunk_path(folder: Path, k: int) -> Path:
    return folder / f"frames-{k:05d}.bin"


def read_meta(folder: Path) -> dict[str, Any]:
    p = folder / META
    if not p.exists():
        raise RunDataError(f"{folder}: no {META}: not a run's data folder")
    meta = json.loads(p.read_text())
    fmt = meta.get("format")
    version = fmt.removeprefix(FORMAT_FAMILY) if isinstance(fmt, str) else ""
    if not isinstance(fmt, str) or not fmt.startswith(FORMAT_FAMILY) or not version.isdigit():
        raise RunDataError(f"{p}: format {fmt!r}, not a run's data ({FORMAT_FAMILY}N)")
    if int(version) > FORMAT_VERSION:
        raise RunDataError(f"{p}: format {fmt}, written by a newer build than this one "
                           f"({FORMAT}); read it with that build")
    return meta


def check_appendable(folder: Path, meta: dict[str, Any]) -> None:
    """RunDataError (one line) unless this build's frames may be appended to ``folder``:
    the same format version and frame layout, else a resume would write frames of
    another size under the stored dtype."""
    if meta.get("format") == FORMAT and meta.get("dtype") == frame_layout():
        return
    raise RunDataError(
        f"{folder}: its frames are format {meta.get('format')} ({len(meta.get('dtype', []))} "
        f"fields), this build writes {FORMAT} ({len(frame_layout())} fields); a run is "
        "resumed only by a build of its own format: finish it with the build that wrote "
        "it (run.json code), or keep its data (testbed export) and start a new run")


def dtype_of(meta: dict[str, Any]) -> np.dtype:
    """The frame dtype a folder was written with (from its meta.json)."""
    return np.dtype([(name, kind, tuple(shape)) if shape else (name, kind)
                     for name, kind, shape in meta["dtype"]])


def frame_layout() -> list[list[Any]]:
    """``FRAME_DTYPE`` as meta.json records it: [name, numpy type, shape] per field."""
    fields = FRAME_DTYPE.fields or {}
    return [[name, fields[name][0].base.str, list(fields[name][0].shape)]
            for name in FRAME_DTYPE.names or ()]


class RunData:
    """A run's data folder, for reading: complete steps only (see ``num_steps``)."""

    def __init__(self, folder: str | os.PathLike[str]) -> None:
        self.folder = Path(folder)
        self.meta = read_meta(self.folder)
        self.robots: list[str] = list(self.meta["robots"])
        self.steps_per_chunk = int(self.meta["steps_per_chunk"])
        self.dtype = dtype_of(self.meta)

    @classmethod
    def of_run(cls, run_dir: str | os.PathLike[str]) -> RunData:
        return cls(Path(run_dir) / FOLDER)

    def _chunks(self) -> list[Path]:
        out = []
        while _chunk_path(self.folder, len(out)).exists():
            out.append(_chunk_path(self.folder, len(out)))
        return out

    @property
    def num_steps(self) -> int:
        """Steps whose every arm's frame is on disk (a torn last record is not counted)."""
        per_step = self.dtype.itemsize * len(self.robots)
        chunks = self._chunks()
        if not chunks:
            return 0
        full = (len(chunks) - 1) * self.steps_per_chunk
        return full + chunks[-1].stat().st_size // per_step

    def frames(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Frames of steps [start, stop) as one array (N_steps * N_arms,), step-major."""
        stop = self.num_steps if stop is None else min(stop, self.num_steps)
        parts = [block for _, block in self.iter_steps(start, stop)]
        return np.concatenate(parts) if parts else np.zeros(0, self.dtype)

    def iter_steps(self, start: int = 0, stop: int | None = None
                   ) -> Iterator[tuple[int, np.ndarray]]:
        """(t, frames of step t: one per arm, in ``robots`` order), read chunk by chunk."""
        stop = self.num_steps if stop is None else min(stop, self.num_steps)
        n = len(self.robots)
        t = start
        while t < stop:
            k, first = divmod(t, self.steps_per_chunk)
            last = min(stop, (k + 1) * self.steps_per_chunk)
            block = np.fromfile(_chunk_path(self.folder, k), dtype=self.dtype,
                                count=(last - t) * n, offset=first * n * self.dtype.itemsize)
            for i in range(last - t):
                yield t + i, block[i * n : (i + 1) * n]
            t = last


class RunDataWriter:
    """Appends each step's frames to a run's data folder, durably (write, fsync).

    Opening an existing folder (resume) cuts it back to ``keep_steps`` complete steps:
    the steps the checkpoint holds, as steps.jsonl is cut back.
    """

    def __init__(self, run_dir: str | os.PathLike[str], robots: list[str],
                 keep_steps: int = 0) -> None:
        self.folder = Path(run_dir) / FOLDER
        self.robots = list(robots)
        if (self.folder / META).exists():
            meta = read_meta(self.folder)
            check_appendable(self.folder, meta)
            if meta["robots"] != self.robots:
                raise RunDataError(f"{self.folder}: written for robots {meta['robots']}, "
                                   f"not {self.robots}")
            self.steps_per_chunk = int(meta["steps_per_chunk"])
        else:
            self.folder.mkdir(parents=True, exist_ok=True)
            self.steps_per_chunk = steps_per_chunk(len(self.robots))
            atomic_write_json(self.folder / META, {
                "format": FORMAT, "robots": self.robots,
                "steps_per_chunk": self.steps_per_chunk, "modes": list(MODES),
                "dtype": frame_layout(), "itemsize": FRAME_DTYPE.itemsize,
            })
        self.steps = self._cut(keep_steps)
        self._file: Any = None
        self._chunk = -1

    def _cut(self, keep: int) -> int:
        """Drop every frame of step >= ``keep`` (and a torn record); return the steps."""
        have = RunData(self.folder).num_steps
        keep = min(keep, have)
        per_step = FRAME_DTYPE.itemsize * len(self.robots)
        k = 0
        while _chunk_path(self.folder, k).exists():
            lo = k * self.steps_per_chunk
            path = _chunk_path(self.folder, k)
            if keep <= lo and k > 0:
                path.unlink()
            else:
                size = (min(keep, lo + self.steps_per_chunk) - lo) * per_step
                if path.stat().st_size != size:
                    with open(path, "r+b") as f:
                        f.truncate(size)
                        os.fsync(f.fileno())
            k += 1
        fsync_dir(self.folder)
        return keep

    def append(self, frames: np.ndarray) -> None:
        """Write step ``self.steps``'s frames (one per robot) and fsync."""
        if frames.dtype != FRAME_DTYPE or len(frames) != len(self.robots):
            raise RunDataError(f"a step is {len(self.robots)} frames of FRAME_DTYPE")
        if int(frames["t"][0]) != self.steps:
            raise RunDataError(f"step {int(frames['t'][0])} written after "
                               f"{self.steps} steps")
        k = self.steps // self.steps_per_chunk
        if k != self._chunk:
            self.close()
            path = _chunk_path(self.folder, k)
            new = not path.exists()
            self._file = open(path, "ab")  # noqa: SIM115 (closed in close())
            self._chunk = k
            if new:
                fsync_dir(self.folder)
        self._file.write(frames.tobytes())
        self._file.flush()
        os.fsync(self._file.fileno())
        self.steps += 1

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
            self._chunk = -1


# ----------------------------------------------------------------- the learner's data
class DataSink(Protocol):
    def add_human(self, images: np.ndarray, actions: np.ndarray,
                  labellers: np.ndarray | None = None) -> None: ...

    def add_transitions(self, images: np.ndarray, actions: np.ndarray,
                        next_images: np.ndarray, violation: np.ndarray,
                        success: np.ndarray) -> None: ...


def pushed(frames: np.ndarray) -> np.ndarray:
    """Arms whose push went out at this step (autonomous or teleop, not refused or
    faulted): the ones whose next observation makes a critic transition."""
    return (frames["action"] >= 0) & np.isin(frames["mode"], (_AUTONOMOUS, _TELEOP))


def add_transitions(sink: DataSink, prev: np.ndarray, observed: np.ndarray,
                    images: np.ndarray) -> None:
    """The critics' (s, a, s') from the pushes of ``prev`` (the last step's frames)
    to this step's observation; an arm not observed now gives none."""
    done = pushed(prev) & observed
    if done.any():
        sink.add_transitions(prev["image"][done], prev["action"][done].astype(np.int64),
                             images[done], prev["violation"][done], prev["success"][done])


def add_labels(sink: DataSink, frames: np.ndarray) -> None:
    """The policy's human labels of one step: every teleop push, with its labeller (the
    frame's ``human``: the run's human index, which run.json names), so a learner can
    weigh a label by who gave it."""
    teleop = (frames["mode"] == _TELEOP) & (frames["action"] >= 0)
    if teleop.any():
        sink.add_human(frames["image"][teleop], frames["action"][teleop].astype(np.int64),
                       labellers=frames["human"][teleop].astype(np.int64))


def label_feed(sink: object, num_arms: int) -> LabelFeed | None:
    """The feed of the robot's own pushes for a sink that learns from them (its
    ``robot_frames``; ``Learner`` with ``weighting = "intervention"``), else None."""
    if not getattr(sink, "robot_frames", False):
        return None
    return LabelFeed(num_arms, int(sink.pre_intervention_steps))  # type: ignore[attr-defined]


def replay(sink: DataSink, data: RunData, steps: int) -> None:
    """Give ``sink`` what the fleet loop gave its learner over steps [0, steps): in the
    same order and chunks (so the augmentation seeds and bootstrap weights are the
    same), no transition across a resume (a new session: the world may have moved);
    the robot's own pushes as their episodes ended, to a sink that takes them."""
    if data.num_steps < steps:  # before any call: the sink is left untouched
        raise RunDataError(f"{data.folder}: {data.num_steps} steps on disk, "
                           f"the checkpoint needs {steps}")
    feed = label_feed(sink, len(data.robots))
    prev: np.ndarray | None = None
    for _, frames in data.iter_steps(0, steps):
        if prev is not None and prev["session"][0] == frames["session"][0]:
            add_transitions(sink, prev, frames["observed"], frames["image"])
        add_labels(sink, frames)
        if feed is not None:
            feed.step(sink, frames)  # type: ignore[arg-type]
        prev = frames
