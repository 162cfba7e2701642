"""What the failure head reads of a finished run: each policy push's trunk features under
the run's theta_0 (issue 36, item 3; ``testbed/monitor/failure_head.py``).

Why theta_0's trunk: it is fixed before the run's first step and kept with it
(``learner-start.pt``), so the features of a push never depend on what the run went on
to learn from it, and runs from different theta_0 let the report score a head on
policies it never saw (leave one theta_0 out). Live, the monitor reads the current
policy's features instead (what that costs is measured in docs/notes/monitor.md).

The features are computed once per run and kept beside its records in
``monitor-features.npz`` (the frames they belong to, theta_0's digest), since a report
reads a protocol's runs after every trial of an ``until``.
"""

from __future__ import annotations

import hashlib
import pickle
from pathlib import Path
from typing import Final

import numpy as np

from testbed.records.run_dir import START_LEARNER
from testbed.records.store import RunData, RunDataError

__all__ = ["CACHE", "push_features", "theta0_digest"]

CACHE: Final = "monitor-features.npz"
BATCH: Final = 1024
"""Images read before they go through theta_0 (12 MB): a 100-arm run's are never all in
memory."""


def theta0_digest(run: Path) -> str | None:
    """SHA-256 of the run's theta_0 (``learner-start.pt``), None without one."""
    path = run / START_LEARNER
    if not path.is_file():
        return None
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def push_features(run: Path, frames: np.ndarray, digest: str) -> np.ndarray | str:
    """Trunk features (len(frames), 64) under theta_0 of the run's data-store frames at
    indices ``frames`` (step-major), or why there are none."""
    cache = run / CACHE
    if cache.is_file():
        try:
            with np.load(cache) as kept:
                if str(kept["digest"]) == digest and np.array_equal(kept["frames"], frames):
                    return np.asarray(kept["features"])
        except (OSError, ValueError, KeyError):
            pass  # an old or torn cache: computed again
    try:
        data = RunData.of_run(run)
    except RunDataError as exc:
        return f"no data store with images ({exc})"
    from testbed.learning.features import PolicyFeatures  # torch: only when computed
    from testbed.learning.networks import TRUNK_FEATURES

    try:
        features = PolicyFeatures(run / START_LEARNER)
    except (OSError, ValueError, RuntimeError, KeyError, pickle.UnpicklingError) as exc:
        return f"its theta_0 ({START_LEARNER}) could not be read as a policy: {exc}"
    n = max(len(data.robots), 1)
    step, arm = np.divmod(frames, n)
    feats = np.zeros((frames.size, TRUNK_FEATURES), np.float32)
    pending: list[tuple[np.ndarray, np.ndarray]] = []  # (where, images), a batch at a time
    seen = 0

    def flush() -> None:
        if pending:
            where = np.concatenate([w for w, _ in pending])
            feats[where] = features(np.concatenate([i for _, i in pending]))
            pending.clear()

    for t, block in data.iter_steps(0, int(step.max()) + 1 if frames.size else 0):
        at = np.flatnonzero(step == t)  # the pushes of step t (frames are step-major)
        if at.size:
            pending.append((at, block["image"][arm[at]]))
            seen += at.size
        if sum(w.size for w, _ in pending) >= BATCH:
            flush()
    flush()
    if seen < frames.size:
        return "its data store has fewer frames than its records"
    tmp = run / (CACHE + ".tmp.npz")
    try:
        np.savez(tmp, features=feats, frames=frames, digest=np.array(digest))
        tmp.replace(cache)
    except OSError:
        pass  # a folder the report may not write: computed again next time
    return feats
