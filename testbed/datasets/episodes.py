"""The episode model: one arm's frames for one goal, and runs and demos cut into them.

Why: the run's data store (``testbed.records.store``) is step-major, one record per arm
per step, built for appending and resuming. Learning code outside the testbed wants
*episodes*: one arm chasing one goal, frame by frame, with who acted. This module says
what an episode's frames hold (``COLUMNS``, the codes of ``intervention``) and cuts the
store and the offline demonstrations into episodes; every format (``testbed.datasets.npz``,
``testbed.datasets.lerobot``) writes these and reads back ``Frames``.

A new episode starts at the arm's first frame, when the goal changes (a soft reset after
a success, or after too many pushes), when a hard reset ends (mode ``reset`` -> anything
else), and at a new ``session`` (a resume: the world may have moved). A faulted frame
(goal unknown) never starts one. Offline demonstrations (theta_0's ``data/demos.npz``)
are transitions, not sequences: they are chained back into trajectories where one
push's next image is byte-equal to another's image, and each chain (plus its last next
image, a frame without action) becomes an episode with ``intervention`` -1.

Every frame keeps the data store's labels (``t`` is called ``step``) plus
``intervention`` (as in Sirius: -1 offline demonstration, 1 a human acted -- teleop or
hard reset --, 0 otherwise), ``source_index`` (which run or demos file), and its class,
its class episode's outcome and index (``frame_class``, ``episode_outcome``,
``class_episode``: ``testbed.datasets.class_columns``, the rules of
``testbed.records.frame_classes`` with the run's own k); with those
``testbed.datasets.training`` recovers the learner's data exactly. The columns are
derived from the store's ``FRAME_DTYPE`` (``COLUMNS``), so a new store field needs no
edit here; an export of an older layout reads back completed (``read_back``). A frame's
``human`` is an index into its run's people, so the export's meta names them per run
(``testbed_meta``) and ``Frames.person`` says who each index of each source was.

Nothing here imports torch, pyarrow or PyAV: numpy alone.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from testbed.core.types import IMAGE_SIZE, Mode
from testbed.datasets import class_columns
from testbed.datasets.sources import Sources, load_demos
from testbed.records.frame_classes import DEFAULT_PRE_STEPS
from testbed.records.run_classes import pre_steps_of, run_classes
from testbed.records.run_dir import human_names
from testbed.records.store import FRAME_DTYPE, MODES, RunData

FORMAT: Final = "testbed.export/1"
"""``format`` of the codes' description (meta/testbed.json, an npz's ``meta``)."""
FPS: Final = 1
"""Frames per second of the exported timeline: one frame per fleet step. A step takes
0.5-8 s (twin to hardware), so no true rate exists; the real times are in ``wall_time``."""
DEMO, POLICY, HUMAN = -1, 0, 1
DEMO_TASK: Final = "push the cube to its goal (offline demonstration)"
UNKNOWN_GOAL_TASK: Final = "push the cube to its goal (goal not observed)"

Column = tuple[str, str, tuple[int, ...]]
"""An exported column: (name, numpy dtype, shape of one frame's value)."""

RENAMED: Final = {"t": "step"}
"""Store fields exported under another name (LeRobot's ``step`` is the store's ``t``)."""
STORE_COLUMNS: Final = tuple(n for n in FRAME_DTYPE.names or ()
                             if n != "image" and n not in RENAMED)
"""The data store's fields exported under their own names (``t`` is ``step``; the image
is ``observation.images.top``, an npz's ``image``)."""


def _export_dtype(base: np.dtype) -> str:
    """A store field's dtype in the exports: integers widen to int64 (the store packs
    them in 1-4 bytes; LeRobot and the learner index with int64), bools and floats keep
    theirs (float32 stays float32: nothing is gained by widening a measurement)."""
    return "int64" if base.kind in "iu" else base.name


def _store_column(name: str) -> Column:
    base, shape = FRAME_DTYPE[name].base, FRAME_DTYPE[name].shape
    return (RENAMED.get(name, name), _export_dtype(base), shape)


EXPORT_ONLY: Final[tuple[Column, ...]] = (
    ("intervention", "int64", ()),
    *((name, "int64", ()) for name in class_columns.CLASS_COLUMNS),
    ("source_index", "int64", ()),
)
"""The columns an export adds to the store's: who acted, Sirius-style; the frame's
class, its class episode's outcome and index; which run or demos file it came from."""

COLUMNS: Final[tuple[Column, ...]] = (
    *(_store_column(n) for n in FRAME_DTYPE.names or () if n != "image"), *EXPORT_ONLY)
"""Per-frame labels beside the image, every format's: the store's ``FRAME_DTYPE``
(derived here, so a new store field is exported with no edit) and ``EXPORT_ONLY``."""

ESSENTIAL: Final = frozenset({"action", "intervention", "mode", "human", "success",
                              "violation", "observed", "goal", "step", "arm", "session",
                              "source_index"})
"""The columns the readers need to recover the learner's data and the classes
(``testbed.datasets.training``, ``class_columns.derive``): an export without one is not
the testbed's. Any other column missing from an older export is filled (``fill_value``)."""


def fill_value(dtype: str) -> Any:
    """What a column holds where its value is not known: -1 for a code or index (as the
    store's "none"), NaN for a measurement, False for a flag."""
    kind = np.dtype(dtype).kind
    return -1 if kind in "iu" else (False if kind == "b" else np.nan)

INDEX_COLUMNS: Final[tuple[tuple[str, str], ...]] = (
    ("timestamp", "float32"), ("frame_index", "int64"), ("episode_index", "int64"),
    ("index", "int64"), ("task_index", "int64"),
)
"""LeRobot's bookkeeping columns, in every format."""

MODE_CODE: Final = {m: MODES.index(m.value) for m in Mode}
"""A ``Mode`` -> its code in the ``mode`` column (the data store's)."""
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
class Frames:
    """A whole exported dataset in memory, in ``index`` order."""

    columns: dict[str, np.ndarray]
    """``COLUMNS`` and ``INDEX_COLUMNS``."""
    images: np.ndarray
    tasks: list[str]
    notes: list[str] = field(default_factory=list)
    """What reading it back derived or could not (one line each; the verbs print them)."""
    sources: list[str] = field(default_factory=list)
    """``source_index`` -> what it was (a run's folder, ``demos:<file>``)."""
    people: dict[int, list[str | None]] = field(default_factory=dict)
    """``source_index`` -> its people by human index (run.json's names; None: one the
    config did not name), for the sources that list them; a frame's ``human`` is an
    index into its source's."""
    origin: str = ""
    """Where these frames were read from (what an unnamed human is labelled by)."""

    def __len__(self) -> int:
        return int(self.images.shape[0])

    def person(self, source: int, human: int) -> str:
        """Who human index ``human`` of source ``source`` was: their name where the
        source names its people, else a label of that source and index alone, which
        says it is no name (``"human 1 of runs/x (unnamed)"``), so two sources' index 1
        are never taken for one person."""
        names = self.people.get(source) or []
        name = names[human] if 0 <= human < len(names) else None
        if name is not None:
            return name
        where = (self.sources[source] if 0 <= source < len(self.sources)
                 else f"source {source} of {self.origin or 'this dataset'}")
        return f"human {human} of {where} (unnamed)"


# ----------------------------------------------------------------- cutting episodes
def episode_starts(frames: np.ndarray) -> np.ndarray:
    """Where one arm's frames (time order) start a new episode (bool per frame)."""
    n = len(frames)
    start = np.zeros(n, bool)
    if n == 0:
        return start
    start[0] = True
    start[1:] |= frames["session"][1:] != frames["session"][:-1]
    reset = frames["mode"] == MODE_CODE[Mode.RESET]
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
    human = np.isin(mode, (MODE_CODE[Mode.TELEOP], MODE_CODE[Mode.RESET]))
    return np.where(human, HUMAN, POLICY).astype(np.int64)


def run_episodes(run: Path, steps: int, source_index: int) -> Iterator[Episode]:
    """A run's episodes: arm by arm, each arm's in time order."""
    data = RunData.of_run(run)
    frames = data.frames(0, steps)
    n_arms = len(data.robots)
    classes = run_classes(run, steps=steps)  # the same steps, the run's own k
    for arm, robot in enumerate(data.robots):
        f = frames[arm::n_arms]
        cls = class_columns.of_run(classes, arm)
        starts = np.flatnonzero(episode_starts(f))
        for lo, hi in zip(starts, [*starts[1:], len(f)], strict=True):
            e = f[lo:hi]
            # every field of the store (a new one too), under its export name
            cols = {RENAMED.get(name, name): e[name] for name in FRAME_DTYPE.names or ()
                    if name != "image"}
            cols.update(intervention=_intervention(e["mode"]),
                        source_index=np.full(len(e), source_index),
                        **{k: v[lo:hi] for k, v in cls.items()})
            yield Episode(_typed(cols, len(e)), np.ascontiguousarray(e["image"]),
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


def demo_episodes(path: Path, source_index: int) -> Iterator[Episode]:
    """Offline demonstrations as episodes: each chain's pushes, then its last next
    image as a final frame with no action (so its last transition is kept)."""
    d = load_demos(path)
    for k, chain in enumerate(demo_chains(d["images"], d["next_images"])):
        n = len(chain) + 1
        idx = np.asarray(chain)
        images = np.concatenate([d["images"][idx], d["next_images"][idx[-1:]]])
        outcome = class_columns.demo_outcome(d["success"][idx], d["violation"][idx])
        # what a demonstration knows; every other column (a store field added later
        # too) is ``fill_value``'s "not known": no human of a fleet, no arm, no goal...
        cols = {**class_columns.of_demo(n, outcome, k),
                "action": _then(d["actions"][idx], -1),
                "intervention": np.full(n, DEMO), "mode": np.full(n, MODE_CODE[Mode.TELEOP]),
                "success": _then(d["success"][idx], False),
                "violation": _then(d["violation"][idx], False),
                "observed": np.ones(n, bool), "step": np.arange(n), "session": np.zeros(n),
                "source_index": np.full(n, source_index)}
        yield Episode(_typed(cols, n), images.astype(np.uint8), DEMO_TASK, source_index, "")


def _then(values: np.ndarray, last: Any) -> np.ndarray:
    """``values`` and one more (the final frame's)."""
    return np.concatenate([values, np.asarray([last], dtype=values.dtype)])


def _typed(cols: dict[str, np.ndarray], n: int) -> dict[str, np.ndarray]:
    """``cols`` as ``COLUMNS`` say (dtype, shape), a column not given ``fill_value``."""
    return {name: (np.asarray(cols[name]).astype(dtype, copy=False).reshape(-1, *shape)
                   if name in cols else np.full((n, *shape), fill_value(dtype), dtype))
            for name, dtype, shape in COLUMNS}


def iter_episodes(src: Sources) -> Iterator[Episode]:
    """Every run's episodes (one run in memory at a time), then the demonstrations'."""
    for k, (run, steps) in enumerate(src.runs):
        yield from run_episodes(run, steps, k)
    for k, demos in enumerate(src.demos):
        yield from demo_episodes(demos, len(src.runs) + k)


# ----------------------------------------------------------------- numbering, metadata
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


def gather(episodes: Iterable[Episode], fps: int = FPS) -> Frames:
    """``episodes`` numbered and concatenated into one ``Frames``."""
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


def read_back(frames: Frames, meta: dict[str, Any], where: str) -> Frames:
    """``frames`` as read from an export (``meta``: its meta/testbed.json, an npz's
    ``meta``), completed for an older layout: a column it lacks (a store field added
    since) filled with ``fill_value``, the class columns derived (``with_classes``),
    its sources and people taken from ``meta`` (none before names: each labeller is
    then its source and index); one note for each thing filled or unknown."""
    c, n = frames.columns, len(frames)
    filled = [(name, dtype, shape) for name, dtype, shape in COLUMNS
              if name not in c and name not in class_columns.CLASS_COLUMNS]
    for name, dtype, shape in filled:
        c[name] = np.full((n, *shape), fill_value(dtype), dtype)
    if filled:
        frames.notes.append(f"{where}: exported before the columns "
                            f"{', '.join(name for name, _, _ in filled)}; read as not known "
                            "(-1, NaN or false)")
    frames.origin = where
    frames.sources = [str(s) for s in meta.get("sources") or []]
    runs = meta.get("runs") or []
    frames.people = {k: [None if p is None else str(p) for p in r["people"]]
                     for k, r in enumerate(runs)
                     if isinstance(r, dict) and isinstance(r.get("people"), list)}
    if any(isinstance(r, dict) and "people" not in r for r in runs):
        frames.notes.append(f"{where}: exported before people's names; its labellers are "
                            "told apart by run and human index only (\"human 0 of <run> "
                            "(unnamed)\")")
    return with_classes(frames, where)


def with_classes(frames: Frames, where: str) -> Frames:
    """``frames`` read from an export written before the class columns: with them
    derived from its own columns (``class_columns.derive``), and a note saying so."""
    c = frames.columns
    if all(k in c for k in class_columns.CLASS_COLUMNS):
        return frames
    c.update(class_columns.derive(c, c["intervention"] == DEMO, c["episode_index"]))
    frames.notes.append(
        f"{where}: exported before frame classes; frame_class, episode_outcome and "
        "class_episode derived from its columns with the default k "
        f"({DEFAULT_PRE_STEPS}), not the run's own")
    return frames


def people_of(src: Sources) -> dict[int, list[str | None]]:
    """``source_index`` -> its people by human index, for the runs whose run.json names
    them (``Frames.people``; an export's ``meta.runs[k].people``)."""
    named = {k: human_names(run) for k, (run, _) in enumerate(src.runs)}
    return {k: names for k, names in named.items() if names is not None}


def of_sources(src: Sources) -> Frames:
    """Run folders and demonstrations read directly (``testbed train --data <run>``):
    their episodes gathered, with the sources and people an export would have named."""
    frames = gather(iter_episodes(src))
    frames.sources, frames.people = src.names, people_of(src)
    return frames


def testbed_meta(src: Sources, fps: int = FPS) -> dict[str, Any]:
    """What the columns' codes mean, and where the frames came from (meta/testbed.json
    of a LeRobot export, ``meta`` of an npz): per run its ``people``, each human index's
    name (null: its run.json names none), since a frame's ``human`` is that run's index."""
    runs = []
    for run, steps in src.runs:
        try:
            options = json.loads((run / "run.json").read_text()).get("options", {})
        except (OSError, ValueError, AttributeError):
            options = {}
        runs.append({"path": str(run), "steps": steps, "robots": RunData.of_run(run).robots,
                     "algorithm": options.get("label") or options.get("algorithm"),
                     "seed": options.get("seed"), "pre_intervention_steps": pre_steps_of(run),
                     "people": human_names(run)})
    return {"format": FORMAT, "fps": fps, "modes": list(MODES),
            "intervention": {str(DEMO): "offline demonstration", str(POLICY):
                             "no human acted (policy, idle, fault, refused)",
                             str(HUMAN): "a human acted (teleop or hard reset)"},
            **class_columns.codes(),
            "sources": src.names, "runs": runs, "notes": src.notes}
