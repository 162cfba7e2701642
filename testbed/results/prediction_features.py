"""What the failure head reads of a finished run: each policy push's trunk features under
the run's theta_0 (issue 36, item 3; ``testbed/monitor/failure_head.py``).

Why theta_0's trunk: it is fixed before the run's first step and kept with it
(``learner-start.pt``), so the features of a push never depend on what the run went on
to learn from it, and runs from different theta_0 let the report score a head on
policies it never saw (leave one theta_0 out, theta_0 identified by a hash of its weights:
``theta0_digest``). Live, the monitor reads the current
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

__all__ = ["CACHE", "WEIGHTS", "push_features", "theta0_digest"]

CACHE: Final = "monitor-features.npz"
BATCH: Final = 1024
"""Images read before they go through theta_0 (12 MB): a 100-arm run's are never all in
memory."""
WEIGHTS: Final = (("policy", "policy", None),)
"""What ``theta0_digest`` hashes of a ``Learner.state_dict`` (name, key, sub-key): the
policy ensemble's parameters, what the failure head reads (its trunk features) and what
acts; not the critics (BC pretrains none, C.U.R. the safety critic, so the two runs of
one trial would count as two theta_0 with one policy), nor the seed, sampler,
optimisers, counters, feature statistics or data."""


def theta0_digest(run: Path) -> str | None:
    """SHA-256 of the run's theta_0 weights (``learner-start.pt``), None without one.

    Why the weights and not the file: a protocol's trials pretrain one theta_0 and save it
    with their own seed, sampler, optimiser state and counters, so a hash of the bytes
    made one network into one theta_0 per trial, and "leave one theta_0 out" was leave one
    trial seed out (issue 45, item 1). This hashes what the head reads, ``WEIGHTS`` (the
    policy ensemble only: not the critics), each tensor's name, dtype, shape and bytes,
    in name order; the file is memory-mapped, so the data a theta_0 also keeps is never
    read. A file that is not a learner checkpoint falls back
    to its bytes ("file:" prefixed): ``push_features`` then names why it is unreadable.
    """
    path = run / START_LEARNER
    if not path.is_file():
        return None
    import torch  # only here: testbed.results imports no torch at import time

    try:
        state = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
        parts = [(name, state[key][sub] if sub else state[key])
                 for name, key, sub in WEIGHTS]
    except (OSError, ValueError, RuntimeError, KeyError, TypeError,
            pickle.UnpicklingError):
        return "file:" + _file_digest(path)
    h = hashlib.sha256()
    for name, tensors in parts:
        for key in sorted(tensors):
            t = tensors[key].detach().contiguous()
            h.update(f"{name}.{key}|{t.dtype}|{tuple(t.shape)}|".encode())
            h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


def _file_digest(path: Path) -> str:
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
