"""A finished (or stopped) run's frame classes, read back from its records.

Why: the classes (``testbed.records.frame_classes``) are derived, never stored, so every
reader that counts or exports them (``testbed export``, the report) asks here for the
same answer: the rules run over the run's data store with the run's own ``k``
(``learning.pre_intervention_steps`` of its config.toml; the default for a run made
before it existed). A run without a data store (made before runs kept their frames), or
whose store lacks a field the rules read, still has its steps.jsonl: the classes are
derived from its rows where they can be, and :attr:`RunClasses.notes` says in plain
words what could not be (steps.jsonl has no goals and no sessions, so a goal change
without a success, a fault that hid an end and a resume are placed by rule, or not at
all).

The store is read without its images (a field view of each chunk, memory-mapped), so
counting a 100-arm run's classes touches a page per frame, not its 12 KB.
"""

from __future__ import annotations

import json
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from testbed.core.backend_registry import DEFAULT_BACKEND, BackendError, backend
from testbed.core.types import MAX_PUSHES_PER_GOAL, EpisodeOutcome, FrameClass, Mode
from testbed.records.frame_classes import DEFAULT_PRE_STEPS, Classes, classify
from testbed.records.steps import RecordError, read_steps
from testbed.records.store import FRAME_DTYPE, MODES, RunData, RunDataError

__all__ = ["LABEL_DTYPE", "RunClasses", "pre_steps_of", "row_frames", "run_classes",
           "store_labels"]

CLASS_FIELDS: Final = ("t", "arm", "session", "observed", "mode", "human", "action",
                       "success", "violation", "goal")
"""The frame fields the rules read."""
LABEL_DTYPE: Final = np.dtype([(n, FRAME_DTYPE.fields[n][0])  # type: ignore[index]
                               for n in FRAME_DTYPE.names or () if n != "image"])
"""A frame without its image: what the rules (and the counts) need."""
STORE: Final = "data store"
ROWS: Final = "steps.jsonl"
_PUSH_MODES: Final = (MODES.index(Mode.AUTONOMOUS.value), MODES.index(Mode.TELEOP.value))
_RESET: Final = MODES.index(Mode.RESET.value)
_FAULT: Final = MODES.index(Mode.FAULT.value)
_TAIL: Final = frozenset(MODES.index(m.value) for m in (Mode.IDLE, Mode.RESET, Mode.FAULT))


@dataclass(frozen=True)
class RunClasses:
    """A run's frames (without images, step-major), each one's class, its episode's
    outcome and index on its arm; where they came from and what could not be derived."""

    robots: list[str]
    pre_steps: int
    frames: np.ndarray
    """``LABEL_DTYPE``, step-major (as ``RunData.frames()``)."""
    classes: Classes
    source: str
    """``"data store"`` or ``"steps.jsonl"``."""
    notes: list[str] = field(default_factory=list)
    """One plain line per thing not derived (empty: the data store had everything)."""

    def class_counts(self) -> dict[str, int]:
        """Frames per class (``FrameClass`` names, lower case)."""
        return {c.name.lower(): int(np.count_nonzero(self.classes.classes == c))
                for c in FrameClass}

    def outcome_counts(self) -> dict[str, int]:
        """Episodes (one arm, one episode index) per outcome: how the arms' episodes
        ended, each counted once however long it was."""
        arms = self.frames["arm"].astype(np.int64)
        key = arms * (1 << 32) + self.classes.episodes.astype(np.int64)
        _, first = np.unique(key, return_index=True)
        ends = self.classes.outcomes[first]
        return {o.name.lower(): int(np.count_nonzero(ends == o)) for o in EpisodeOutcome}


# ----------------------------------------------------------------- the run's k
def _config(run: Path) -> dict[str, Any]:
    try:
        return tomllib.loads((run / "config.toml").read_text())
    except (OSError, tomllib.TOMLDecodeError):
        return {}


def pre_steps_of(run: Path) -> int:
    """The run's k: its config.toml's ``learning.pre_intervention_steps``, else (a run
    from before it, or no config) ``DEFAULT_PRE_STEPS``."""
    k = _config(run).get("learning", {}).get("pre_intervention_steps", DEFAULT_PRE_STEPS)
    return int(k) if isinstance(k, int) and not isinstance(k, bool) and k >= 0 \
        else DEFAULT_PRE_STEPS


# ----------------------------------------------------------------- from the data store
def store_labels(data: RunData, stop: int | None = None) -> np.ndarray:
    """Steps [0, stop) of the store as ``LABEL_DTYPE`` frames (no images): each chunk
    memory-mapped and its label fields copied. Fields the store's layout lacks stay
    zero (the caller checks ``missing_fields``)."""
    stop = data.num_steps if stop is None else min(stop, data.num_steps)
    n = len(data.robots)
    out = np.zeros(stop * n, LABEL_DTYPE)
    have = [f for f in LABEL_DTYPE.names or () if f in (data.dtype.names or ())]
    t = 0
    while t < stop:
        k, first = divmod(t, data.steps_per_chunk)
        last = min(stop, (k + 1) * data.steps_per_chunk)
        chunk = np.memmap(data.folder / f"frames-{k:05d}.bin", dtype=data.dtype, mode="r",
                          offset=first * n * data.dtype.itemsize, shape=((last - t) * n,))
        for name in have:
            out[name][t * n:last * n] = chunk[name]
        del chunk
        t = last
    return out


def missing_fields(data: RunData) -> list[str]:
    """The fields the rules read that this store's layout (an older one) lacks."""
    return [f for f in CLASS_FIELDS if f not in (data.dtype.names or ())]


# ----------------------------------------------------------------- from steps.jsonl
def _sessions(rows: Sequence[dict[str, Any]], resumed: Sequence[float]) -> np.ndarray | None:
    """Each row's session: how many resumes (run.json ``resumed``, their start times)
    came before its ``wall_time``; None when rows lack ``wall_time``."""
    times = [r.get("wall_time") for r in rows]
    if any(not isinstance(x, int | float) for x in times):
        return None
    marks = np.sort(np.asarray([float(x) for x in resumed], np.float64))
    return np.searchsorted(marks, np.asarray(times, np.float64), side="right")


def row_frames(rows: Sequence[dict[str, Any]], robots: Sequence[str],
               resumed: Sequence[float] = (), twin: bool = False
               ) -> tuple[np.ndarray, list[str]]:
    """``LABEL_DTYPE`` frames rebuilt from steps.jsonl rows, and what could not be.

    Rows have who acted, the push, success and violation, not the goal nor the session.
    Goals are made up so that the rules cut where the world changed the goal: after a
    success, when a hard reset ends, at a resume (the session from run.json
    ``resumed`` against each row's ``wall_time``; a resumed world is taken as new), and
    on a twin (``twin``) after ``MAX_PUSHES_PER_GOAL`` pushes without either, its
    timeout. A frame of mode fault is not observed."""
    n, s = len(robots), len(rows)
    out = np.zeros(s * n, LABEL_DTYPE)
    sessions = _sessions(rows, resumed)
    notes = [f"no data store: classes from {ROWS}, no images"]
    if sessions is None:
        sessions = np.zeros(s, np.int64)
        if resumed:
            notes.append(f"{ROWS} has no wall_time: its resumes are not placed (one session)")
    elif resumed:
        notes.append("a resume is taken as a new goal (steps.jsonl has none): the "
                     "episode it cut is OPEN")
    notes.append("no goals in steps.jsonl: an end hidden by a fault is not seen (no "
                 "UNKNOWN)" + ("" if twin else "; an episode ended by a new goal without a "
                               "success (a timeout) runs on into the next"))
    goal = np.zeros(n, np.int64)
    pushes = np.zeros(n, np.int64)
    prev_mode = np.full(n, -1)
    # after a violation, while idle, reset or fault: the violated episode's, whatever
    # happens to the world meanwhile (its goal changes when the reset ends)
    tail = np.zeros(n, bool)
    for i, row in enumerate(rows):
        f = out[i * n:(i + 1) * n]
        f["t"], f["session"], f["arm"] = int(row["t"]), sessions[i], np.arange(n)
        for a, r in enumerate(row["robots"][:n]):
            mode = MODES.index(r["mode"])
            resumed_here = i > 0 and sessions[i] != sessions[i - 1]
            ended = tail[a] and mode not in _TAIL
            tail[a] &= not ended
            if (resumed_here and not tail[a]) or ended or prev_mode[a] == _RESET != mode:
                goal[a], pushes[a] = goal[a] + 1, 0
            f["mode"][a], prev_mode[a] = mode, mode
            f["human"][a] = -1 if r.get("human") is None else r["human"]
            f["action"][a] = -1 if r.get("action") is None else r["action"]
            f["success"][a], f["violation"][a] = bool(r["success"]), bool(r["violation"])
            f["uncertainty"][a] = np.nan if r.get("uncertainty") is None else r["uncertainty"]
            f["risk"][a] = np.nan if r.get("risk") is None else r["risk"]
            f["wall_time"][a] = float(row.get("wall_time", np.nan))
            f["observed"][a] = mode != _FAULT
            f["goal"][a] = (goal[a], 0.0) if mode != _FAULT else (np.nan, np.nan)
            pushes[a] += f["action"][a] >= 0 and mode in _PUSH_MODES
            tail[a] |= bool(f["violation"][a])
            if f["success"][a] or (twin and pushes[a] >= MAX_PUSHES_PER_GOAL
                                   and not f["violation"][a]):
                goal[a], pushes[a] = goal[a] + 1, 0
    return out, notes


def _twin_fleet(run: Path) -> bool:
    """Every host of the run's config is simulated (its backend's capability: the twin's
    timeout is a rule of the simulation); a backend not installed here is not."""
    hosts = _config(run).get("hosts")
    if not hosts:
        return False
    try:
        return all(backend(str(h.get("backend", DEFAULT_BACKEND))).capabilities.simulated
                   for h in hosts)
    except BackendError:
        return False


def _resumed(run: Path) -> list[float]:
    try:
        meta = json.loads((run / "run.json").read_text())
    except (OSError, ValueError):
        return []
    marks = meta.get("resumed", []) if isinstance(meta, dict) else []
    return [float(x) for x in marks if isinstance(x, int | float)]


# ----------------------------------------------------------------- the entry point
def run_classes(run: str | Path, pre_steps: int | None = None, steps: int | None = None
                ) -> RunClasses:
    """The classes of ``run``'s first ``steps`` complete steps (default: every step in
    both its data store and its steps.jsonl), with ``k`` = ``pre_steps`` (default: the
    run's own, ``pre_steps_of``). From the data store when it has the fields the rules
    read; else from steps.jsonl, with notes. RunDataError when neither can be read."""
    run = Path(run)
    k = pre_steps_of(run) if pre_steps is None else int(pre_steps)
    try:
        rows: list[dict[str, Any]] | None = read_steps(run / ROWS, validate=False)
    except (OSError, RecordError):
        rows = None
    try:
        data: RunData | None = RunData.of_run(run)
    except RunDataError:
        data = None
    notes: list[str] = []
    if data is not None:
        lacking = missing_fields(data)
        if not lacking:
            stop = data.num_steps if rows is None else min(data.num_steps, len(rows))
            stop = stop if steps is None else min(stop, steps)
            frames = store_labels(data, stop)
            return RunClasses(list(data.robots), k, frames,
                              classify(frames, len(data.robots), k), STORE)
        notes.append(f"its data store (format {data.meta.get('format')}) has no "
                     f"{', '.join(lacking)}")
    if rows is None:
        raise RunDataError(f"{run}: neither a data store nor a readable {ROWS}")
    rows = rows if steps is None else rows[:steps]
    robots = [r["robot"] for r in rows[0]["robots"]] if rows else []
    frames, why = row_frames(rows, robots, _resumed(run), _twin_fleet(run))
    if notes:
        why[0] = f"{notes[0]}: classes from {ROWS}, no images"
    return RunClasses(robots, k, frames, classify(frames, len(robots), k), ROWS, why)
