"""A run's data as a dataset others can read (``testbed export``), and back (``testbed train``).

Why: the run's data store (``testbed.records.store``) is built for appending and resuming,
step-major, one record per arm per step. Learning code outside the testbed (LeRobot,
Sirius-style intervention learning, a notebook) wants *episodes*: one arm chasing one
goal, frame by frame, with who acted. This module cuts the store into such episodes
and writes them as plain numpy arrays (``--format npz``) or, through
``testbed.datasets.lerobot``, as a LeRobot v3 dataset; ``testbed train`` reads either
back (or a run folder directly) and pretrains a learner on it.

An episode is one arm's frames for one goal. A new one starts at the arm's first
frame, when the goal changes (a soft reset after a success, or after too many pushes),
when a hard reset ends (mode ``reset`` -> anything else), and at a new ``session`` (a
resume: the world may have moved). A faulted frame (goal unknown) never starts one.
Offline demonstrations (theta_0's ``data/demos.npz``) are transitions, not sequences:
they are chained back into trajectories where one push's next image is byte-equal to
another's image, and each chain (plus its last next image, a frame without action)
becomes an episode with ``intervention`` -1.

Every frame keeps the data store's labels (``t`` is called ``step``) plus
``intervention`` (as in Sirius: -1 offline demonstration, 1 a human acted -- teleop or
hard reset --, 0 otherwise) and ``source_index`` (which run or demos file). Those make
the learner's data recoverable exactly (:func:`training_data`): the human labels are
the frames with ``intervention`` != 0 and an action, the critics' transitions every
push whose arm's next frame (same source, arm and session, step + 1) was observed --
what ``testbed.records.store.replay`` gives a resumed learner, across episode boundaries too
(a success's transition ends one episode and its next image starts the next).

Nothing here imports torch, pyarrow or PyAV: the npz path needs numpy alone, and the
LeRobot path checks for the ``export`` extra before importing ``lerobot_format``.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import sys
import tempfile
import zipfile
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from testbed.core.config import ConfigError
from testbed.core.types import IMAGE_SIZE, Mode
from testbed.records.steps import RecordError, read_steps
from testbed.records.store import MODES, RunData, RunDataError

FORMAT: Final = "testbed.datasets.episodes/1"
FPS: Final = 1
"""Frames per second of the exported timeline: one frame per fleet step. A step takes
0.5-8 s (twin to hardware), so no true rate exists; the real times are in ``wall_time``."""
NPZ_NAME: Final = "frames.npz"
DEMO, POLICY, HUMAN = -1, 0, 1
DEMO_TASK: Final = "push the cube to its goal (offline demonstration)"
UNKNOWN_GOAL_TASK: Final = "push the cube to its goal (goal not observed)"
DEMO_FIELDS: Final = ("images", "actions", "next_images", "violation", "success")
"""``testbed.experiments.pretraining.FIELDS`` (not imported: that module pulls in the fleet)."""

COLUMNS: Final[tuple[tuple[str, str, tuple[int, ...]], ...]] = (
    ("action", "int64", ()),
    ("intervention", "int64", ()),
    ("mode", "int64", ()),
    ("human", "int64", ()),
    ("success", "bool", ()),
    ("violation", "bool", ()),
    ("observed", "bool", ()),
    ("uncertainty", "float32", ()),
    ("risk", "float32", ()),
    ("goal", "float32", (2,)),
    ("wall_time", "float64", ()),
    ("step", "int64", ()),
    ("arm", "int64", ()),
    ("session", "int64", ()),
    ("source_index", "int64", ()),
)
"""Per-frame labels beside the image: (name, numpy dtype, shape of one frame's value)."""

INDEX_COLUMNS: Final[tuple[tuple[str, str], ...]] = (
    ("timestamp", "float32"), ("frame_index", "int64"), ("episode_index", "int64"),
    ("index", "int64"), ("task_index", "int64"),
)
"""LeRobot's bookkeeping columns, in every format."""

_MODE = {m: MODES.index(m.value) for m in Mode}
IMAGE_SHAPE: Final = (IMAGE_SIZE, IMAGE_SIZE, 3)


@dataclass
class Episode:
    """One episode: its frames' ``COLUMNS`` and images, in time order."""

    columns: dict[str, np.ndarray]
    images: np.ndarray
    task: str
    source_index: int
    robot: str
    """The arm's name; "" for offline demonstrations."""

    def __len__(self) -> int:
        return int(self.images.shape[0])


@dataclass
class Sources:
    """What an export reads: runs with a data store, the demonstrations files (each
    once, however many runs share it), and one line per thing left out."""

    runs: list[tuple[Path, int]] = field(default_factory=list)
    """(run folder, complete steps)."""
    demos: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        """``source_index`` -> what it is (runs first, then demonstrations files)."""
        return [str(r) for r, _ in self.runs] + [f"demos:{d}" for d in self.demos]


# ----------------------------------------------------------------- finding the data
def complete_steps(run: Path) -> int:
    """Steps both in the data store and in steps.jsonl (a crash may leave one ahead);
    RecordError if steps.jsonl cannot be read, RunDataError without a data store."""
    stored = RunData.of_run(run).num_steps
    return min(stored, len(read_steps(run, validate=False)))


def _run_folders(d: Path) -> list[Path]:
    if (d / "steps.jsonl").exists():
        return [d]
    return sorted(p.parent for p in d.glob("*/steps.jsonl"))


def _demos_of(run: Path) -> tuple[Path | None, str | None]:
    """The run's theta_0 demonstrations, or why there are none (one line)."""
    own = run / "data" / "demos.npz"
    if own.exists():
        return own, None
    cached = sorted((run.parent / ".pretrained").glob("*/demos.npz"))
    if len(cached) == 1:
        return cached[0], None
    why = "none" if not cached else f"{len(cached)}, not one"
    return None, (f"{run}: no data/demos.npz and {why} in ../.pretrained/*/demos.npz; "
                  "its offline demonstrations are not exported")


def find_sources(dirs: Sequence[Path], flag: str = "RUN_OR_PROTOCOL_DIR") -> Sources:
    """The runs in or below ``dirs`` that have a data store, and their demos files."""
    src = Sources()
    seen_demos: set[str] = set()
    for d in dirs:
        if not d.is_dir():
            raise ConfigError(f"{flag}: no such folder {str(d)!r}")
        for run in _run_folders(d):
            try:
                steps = complete_steps(run)
            except RunDataError:
                src.notes.append(f"{run}: no data store (data/meta.json: made before "
                                 "runs kept their frames); skipped")
                continue
            except RecordError as exc:
                src.notes.append(f"{run}: steps.jsonl unreadable ({exc}); skipped")
                continue
            if steps == 0:
                src.notes.append(f"{run}: no complete step in its data store; skipped")
                continue
            src.runs.append((run, steps))
            demos, why = _demos_of(run)
            if why is not None:
                src.notes.append(why)
            if demos is not None:
                digest = hashlib.sha256(demos.read_bytes()).hexdigest()
                if digest in seen_demos:  # a protocol's runs share theta_0's
                    continue
                seen_demos.add(digest)
                try:
                    load_demos(demos)
                except (ConfigError, OSError, ValueError, zipfile.BadZipFile) as exc:
                    why = " ".join(str(exc).split())[:120]
                    src.notes.append(f"{demos}: unreadable ({why}); not exported")
                    continue
                src.demos.append(demos)
    if not src.runs:
        raise ConfigError(f"{flag}: no run with a data store (data/meta.json) in "
                          f"{', '.join(map(str, dirs))}; give run or protocol folders")
    return src


# ----------------------------------------------------------------- cutting episodes
def episode_starts(frames: np.ndarray) -> np.ndarray:
    """Where one arm's frames (time order) start a new episode (bool per frame)."""
    n = len(frames)
    start = np.zeros(n, bool)
    if n == 0:
        return start
    start[0] = True
    start[1:] |= frames["session"][1:] != frames["session"][:-1]
    reset = frames["mode"] == _MODE[Mode.RESET]
    start[1:] |= reset[:-1] & ~reset[1:]
    goal: tuple[float, float] | None = None
    for i in range(n):
        if start[i]:
            goal = None
        if frames["observed"][i]:
            g = (float(frames["goal"][i, 0]), float(frames["goal"][i, 1]))
            if goal is not None and g != goal:
                start[i] = True
            goal = g
    return start


def goal_task(goals: np.ndarray, observed: np.ndarray) -> str:
    """The task string of an episode: its goal, rounded (the first observed frame's)."""
    seen = np.flatnonzero(observed)
    if len(seen) == 0:
        return UNKNOWN_GOAL_TASK
    x, y = goals[seen[0]]
    return f"push the cube to ({float(x):.2f}, {float(y):.2f})"


def _intervention(mode: np.ndarray) -> np.ndarray:
    human = np.isin(mode, (_MODE[Mode.TELEOP], _MODE[Mode.RESET]))
    return np.where(human, HUMAN, POLICY).astype(np.int64)


def run_episodes(run: Path, steps: int, source_index: int) -> Iterator[Episode]:
    """A run's episodes: arm by arm, each arm's in time order."""
    data = RunData.of_run(run)
    frames = data.frames(0, steps)
    n_arms = len(data.robots)
    for arm, robot in enumerate(data.robots):
        f = frames[arm::n_arms]
        starts = np.flatnonzero(episode_starts(f))
        for lo, hi in zip(starts, [*starts[1:], len(f)], strict=True):
            e = f[lo:hi]
            cols = {
                "action": e["action"], "intervention": _intervention(e["mode"]),
                "mode": e["mode"], "human": e["human"], "success": e["success"],
                "violation": e["violation"], "observed": e["observed"],
                "uncertainty": e["uncertainty"], "risk": e["risk"], "goal": e["goal"],
                "wall_time": e["wall_time"], "step": e["t"], "arm": e["arm"],
                "session": e["session"],
                "source_index": np.full(len(e), source_index),
            }
            yield Episode(_typed(cols), np.ascontiguousarray(e["image"]),
                          goal_task(e["goal"], e["observed"]), source_index, robot)


def demo_chains(images: np.ndarray, next_images: np.ndarray) -> list[list[int]]:
    """Demonstrations (transitions) chained into trajectories: ``i`` -> ``j`` when
    ``next_images[i]`` is byte-equal to ``images[j]``, ``j > i`` (pushes are kept in
    the order they were made), the first such ``j`` not taken yet. Any mistaken link
    joins two pushes of equal images, so every transition is still recovered exactly."""
    where: dict[bytes, list[int]] = {}
    for j in range(len(images)):
        where.setdefault(images[j].tobytes(), []).append(j)
    succ = [-1] * len(images)
    taken = [False] * len(images)
    for i in range(len(images)):
        for j in where.get(next_images[i].tobytes(), ()):
            if j > i and not taken[j]:
                succ[i], taken[j] = j, True
                break
    chains = []
    for s in range(len(images)):
        if not taken[s]:
            chain = [s]
            while succ[chain[-1]] >= 0:
                chain.append(succ[chain[-1]])
            chains.append(chain)
    return chains


def load_demos(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as z:
        missing = [k for k in DEMO_FIELDS if k not in z.files]
        if missing:
            raise ConfigError(f"{path}: not a demonstrations file (missing "
                              f"{', '.join(missing)})")
        return {k: z[k] for k in DEMO_FIELDS}


def demo_episodes(path: Path, source_index: int) -> Iterator[Episode]:
    """Offline demonstrations as episodes: each chain's pushes, then its last next
    image as a final frame with no action (so its last transition is kept)."""
    d = load_demos(path)
    for chain in demo_chains(d["images"], d["next_images"]):
        n = len(chain) + 1
        idx = np.asarray(chain)
        images = np.concatenate([d["images"][idx], d["next_images"][idx[-1:]]])
        cols = {
            "action": _then(d["actions"][idx], -1),
            "intervention": np.full(n, DEMO), "mode": np.full(n, _MODE[Mode.TELEOP]),
            "human": np.full(n, -1), "success": _then(d["success"][idx], False),
            "violation": _then(d["violation"][idx], False),
            "observed": np.ones(n, bool), "uncertainty": np.full(n, np.nan),
            "risk": np.full(n, np.nan), "goal": np.full((n, 2), np.nan),
            "wall_time": np.full(n, np.nan), "step": np.arange(n), "arm": np.full(n, -1),
            "session": np.zeros(n), "source_index": np.full(n, source_index),
        }
        yield Episode(_typed(cols), images.astype(np.uint8), DEMO_TASK, source_index, "")


def _then(values: np.ndarray, last: Any) -> np.ndarray:
    """``values`` and one more (the final frame's)."""
    return np.concatenate([values, np.asarray([last], dtype=values.dtype)])


def _typed(cols: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {name: np.asarray(cols[name]).astype(dtype, copy=False).reshape(-1, *shape)
            for name, dtype, shape in COLUMNS}


def iter_episodes(src: Sources) -> Iterator[Episode]:
    """Every run's episodes (one run in memory at a time), then the demonstrations'."""
    for k, (run, steps) in enumerate(src.runs):
        yield from run_episodes(run, steps, k)
    for k, demos in enumerate(src.demos):
        yield from demo_episodes(demos, len(src.runs) + k)


class Numbering:
    """Episode, frame and task indices as episodes come (LeRobot's bookkeeping)."""

    def __init__(self, fps: int = FPS) -> None:
        self.fps = fps
        self.tasks: dict[str, int] = {}
        self.frames = 0
        self.episodes = 0

    def number(self, ep: Episode) -> dict[str, np.ndarray]:
        n = len(ep)
        task = self.tasks.setdefault(ep.task, len(self.tasks))
        frame_index = np.arange(n, dtype=np.int64)
        out = {"timestamp": (frame_index / self.fps).astype(np.float32),
               "frame_index": frame_index,
               "episode_index": np.full(n, self.episodes, np.int64),
               "index": np.arange(self.frames, self.frames + n, dtype=np.int64),
               "task_index": np.full(n, task, np.int64)}
        self.frames += n
        self.episodes += 1
        return out


def testbed_meta(src: Sources, fps: int = FPS) -> dict[str, Any]:
    """What the columns' codes mean, and where the frames came from (meta/testbed.json
    of a LeRobot export, ``meta`` of an npz)."""
    runs = []
    for run, steps in src.runs:
        try:
            options = json.loads((run / "run.json").read_text()).get("options", {})
        except (OSError, ValueError, AttributeError):
            options = {}
        runs.append({"path": str(run), "steps": steps, "robots": RunData.of_run(run).robots,
                     "algorithm": options.get("label") or options.get("algorithm"),
                     "seed": options.get("seed")})
    return {"format": FORMAT, "fps": fps, "modes": list(MODES),
            "intervention": {str(DEMO): "offline demonstration", str(POLICY):
                             "no human acted (policy, idle, fault, refused)",
                             str(HUMAN): "a human acted (teleop or hard reset)"},
            "sources": src.names, "runs": runs, "notes": src.notes}


# ----------------------------------------------------------------- npz
@dataclass
class Frames:
    """A whole exported dataset in memory, in ``index`` order."""

    columns: dict[str, np.ndarray]
    """``COLUMNS`` and ``INDEX_COLUMNS``."""
    images: np.ndarray
    tasks: list[str]

    def __len__(self) -> int:
        return int(self.images.shape[0])


def gather(episodes: Iterable[Episode], fps: int = FPS) -> Frames:
    numbering = Numbering(fps)
    cols: dict[str, list[np.ndarray]] = {}
    images = []
    for ep in episodes:
        for k, v in {**ep.columns, **numbering.number(ep)}.items():
            cols.setdefault(k, []).append(v)
        images.append(ep.images)
    empty = {n: np.zeros((0, *s), d) for n, d, s in COLUMNS}
    empty.update({n: np.zeros(0, d) for n, d in INDEX_COLUMNS})
    return Frames({k: np.concatenate(cols[k]) if k in cols else v for k, v in empty.items()},
                  np.concatenate(images) if images else np.zeros((0, *IMAGE_SHAPE), np.uint8),
                  list(numbering.tasks))


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
    with np.load(path) as z:
        names = [n for n, _, _ in COLUMNS] + [n for n, _ in INDEX_COLUMNS]
        missing = [n for n in ("image", "tasks", *names) if n not in z.files]
        if missing:
            raise ConfigError(f"--data: {path} is not an npz of testbed export (missing "
                              f"{', '.join(missing[:3])})")
        return Frames({n: z[n] for n in names}, z["image"], [str(t) for t in z["tasks"]])


# ----------------------------------------------------------------- the learner's data
@dataclass
class TrainingData:
    """What ``testbed train`` gives the learner: human labels and critic transitions."""

    images: np.ndarray
    actions: np.ndarray
    transitions: dict[str, np.ndarray]
    """``testbed.experiments.pretraining.FIELDS`` -> arrays."""

    @staticmethod
    def merge(parts: Sequence[TrainingData]) -> TrainingData:
        return TrainingData(
            np.concatenate([p.images for p in parts]),
            np.concatenate([p.actions for p in parts]),
            {k: np.concatenate([p.transitions[k] for p in parts]) for k in DEMO_FIELDS})


def training_data(frames: Frames) -> TrainingData:
    """Human labels (``intervention`` != 0 with an action: teleop pushes and the
    demonstrations) and transitions (a push, then its arm's next frame observed)."""
    c = frames.columns
    acted = c["action"] >= 0
    label = acted & (c["intervention"] != POLICY)
    pushed = acted & np.isin(c["mode"], (_MODE[Mode.AUTONOMOUS], _MODE[Mode.TELEOP]))
    same = np.ones(max(len(frames) - 1, 0), bool)
    for k in ("source_index", "arm", "session"):
        same &= c[k][1:] == c[k][:-1]
    pair = np.flatnonzero(pushed[:-1] & same & (c["step"][1:] == c["step"][:-1] + 1)
                          & c["observed"][1:])
    return TrainingData(
        frames.images[label], c["action"][label],
        {"images": frames.images[pair], "actions": c["action"][pair],
         "next_images": frames.images[pair + 1], "violation": c["violation"][pair],
         "success": c["success"][pair]})


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
    if path.is_file() and path.suffix == ".npz":
        return read_npz(path)
    if path.is_dir() and (path / NPZ_NAME).is_file():
        return read_npz(path / NPZ_NAME)
    if path.is_dir() and (path / "meta" / "info.json").is_file():
        video = (path / "videos").is_dir()
        require_export_extra(video)
        from testbed.datasets.lerobot import read_dataset

        return read_dataset(path, flag)
    if path.is_dir():
        src = find_sources([path], flag)
        for note in src.notes:
            sys.stderr.write(f"testbed: {note}\n")
        return gather(iter_episodes(src))
    raise ConfigError(f"{flag}: {str(path)!r} is neither an npz, a LeRobot dataset nor a "
                      "run folder of the testbed")


# ----------------------------------------------------------------- the verb
@dataclass
class ExportResult:
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
