"""Every push of a run valued: ``push_values.npz`` beside the run's data.

Why: issue 46 asks for the value of every push in the records, demonstrations, the
robot's pushes and the humans' alike. The data store holds what was pushed from what
image (``store.py``); the advantage is the value critic's (``testbed/learning/
advantage.py``) and depends on the learner it is read from, so it is not written into
the append-only frames at their step: it is computed after, for a named checkpoint, into
a file of its own that says which (its path and sha256), and computed again whenever
asked (never trusted from an older file: a new checkpoint, a new value).

One row per push of the run (a frame with an action, autonomous or teleop, observed):
its step ``t`` and ``arm``, the ``mode`` (index into ``store.MODES``), the ``action``,
the frame's ``frame_class`` and its episode's ``outcome`` (``frame_classes.classify``:
how the episode the push belongs to ended), and the learner's ``q`` = Q(s, a),
``value`` = Q(s, pi(s)) (its value critic), ``advantage`` = q - value and ``policy_action`` = pi(s).
numpy only here; the caller passes the learner's ``push_values`` (torch stays out of
the records' import).
"""

from __future__ import annotations

import hashlib
import io
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from testbed.core.atomic import atomic_write_bytes
from testbed.core.types import DEFAULT_PRE_STEPS, EpisodeOutcome, FrameClass
from testbed.records.frame_classes import classify
from testbed.records.store import MODES, RunData, pushed

__all__ = ["PUSH_VALUES_FILE", "PushValuesError", "read_push_values", "summary_lines",
           "value_run", "write_push_values"]

PUSH_VALUES_FILE: Final = "push_values.npz"
FORMAT: Final = "testbed.push_values/1"
COLUMNS: Final = ("t", "arm", "mode", "action", "frame_class", "outcome", "q", "value",
                  "advantage", "policy_action")
CHUNK_STEPS: Final = 64
"""Steps of frames read and valued at a time (4 arms: 256 images, the learner's chunk)."""

ValueFn = Callable[[npt.NDArray[np.uint8], npt.NDArray[np.int64]], Any]


class PushValuesError(ValueError):
    """A push values file that is not one, or not for this run's data."""


def file_digest(path: Path) -> str:
    """sha256 of a file (the checkpoint the values were read from)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def value_run(run_dir: Path, value: ValueFn,
              pre_steps: int = DEFAULT_PRE_STEPS) -> dict[str, np.ndarray]:
    """Every push of the run at ``run_dir`` valued by ``value`` (``Learner.push_values``),
    in step order, arms in index order (the module doc's columns)."""
    data = RunData.of_run(run_dir)
    frames = data.frames()
    arms = len(data.robots)
    got = classify(frames, arms, pre_steps)
    rows = np.flatnonzero(pushed(frames) & frames["observed"])
    out: dict[str, list[np.ndarray]] = {c: [] for c in COLUMNS}
    per = CHUNK_STEPS * max(arms, 1)
    for lo in range(0, len(rows), per):
        at = rows[lo:lo + per]
        f = np.asarray(frames[at])
        v = value(np.ascontiguousarray(f["image"]), f["action"].astype(np.int64))
        for name, col in (("t", f["t"]), ("arm", f["arm"]), ("mode", f["mode"]),
                          ("action", f["action"]), ("frame_class", got.classes[at]),
                          ("outcome", got.outcomes[at]), ("q", v.q), ("value", v.value),
                          ("advantage", v.advantage), ("policy_action", v.policy_action)):
            out[name].append(np.asarray(col))
    types = {"t": np.int32, "arm": np.int16, "mode": np.int8, "action": np.int8,
             "frame_class": np.int8, "outcome": np.int8, "q": np.float32,
             "value": np.float32, "advantage": np.float32, "policy_action": np.int8}
    return {c: (np.concatenate(out[c]) if out[c] else np.zeros(0)).astype(types[c])
            for c in COLUMNS}


def write_push_values(run_dir: Path, values: dict[str, np.ndarray], checkpoint: Path
                      ) -> Path:
    """``values`` (:func:`value_run`) into the run's ``push_values.npz``, atomically, with
    what they were read from (``checkpoint``: its path and sha256)."""
    meta = {"format": FORMAT, "checkpoint": str(checkpoint),
            "checkpoint_sha256": file_digest(checkpoint), "pushes": len(values["t"]),
            "robots": RunData.of_run(run_dir).robots}
    buf = io.BytesIO()
    np.savez(buf, meta=np.asarray(json.dumps(meta)), **values)
    path = Path(run_dir) / PUSH_VALUES_FILE
    atomic_write_bytes(path, buf.getvalue())
    return path


def read_push_values(run_dir: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """(meta, columns) of the run's ``push_values.npz``; :class:`PushValuesError` if it is
    not this format. A reader that needs them for another checkpoint computes them
    again (the meta names the one they are of)."""
    path = Path(run_dir) / PUSH_VALUES_FILE
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            cols = {c: z[c] for c in COLUMNS}
    except (OSError, KeyError, ValueError) as exc:
        raise PushValuesError(f"{path}: not a push values file ({exc})") from None
    if meta.get("format") != FORMAT:
        raise PushValuesError(f"{path}: format {meta.get('format')!r}, not {FORMAT!r}")
    return meta, cols


def summary_lines(values: dict[str, np.ndarray]) -> list[str]:
    """One line per who pushed and per class: pushes, mean advantage, share above 0."""
    lines = []
    groups: list[tuple[str, np.ndarray]] = [
        (f"mode {MODES[m]}", values["mode"] == m) for m in sorted(set(values["mode"].tolist()))]
    groups += [(f"class {FrameClass(c).name.lower()}, episode {EpisodeOutcome(o).name.lower()}",
                (values["frame_class"] == c) & (values["outcome"] == o))
               for c, o in sorted({(int(c), int(o)) for c, o in
                                   zip(values["frame_class"], values["outcome"], strict=True)})]
    for name, sel in groups:
        a = values["advantage"][sel]
        lines.append(f"{name}: {a.size} pushes, mean advantage {a.mean():+.4f}, "
                     f"above 0: {np.mean(a > 0):.0%}, mean value {values['value'][sel].mean():.3f}")
    return lines
