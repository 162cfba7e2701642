"""The per-step checkpoint before and after the run's data store (issue 14, item 1).

Before: every step wrote the whole learner, its replay data included (the data copied
in the loop's thread, then ``torch.save`` + fsync in a thread), so the checkpoint grew
with the run. After: the learner's training state (weights, optimisers, sampler,
counters, the data's sizes) plus the step's frames appended to ``data/`` (fsync).
Both measured in this run, on learners holding the data of:

* the end of the default twin trial (README command 1: theta_0's 375 demos and 400
  pretraining transitions, then 250 steps x 4 arms: 1000 transitions, ~300 teleop
  labels);
* 100 steps of ``protocols/twin-scale.toml`` (100 arms: 10,000 transitions, ~2,000
  labels; a 10,000-step run holds 100x that).

Printed per case: size and write time (snapshot in the loop + write, fsynced) before
and after, their ratios, and the data store's append per step.

    .venv/bin/python benchmarks/bench_checkpoint.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import copy
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from testbed.core.types import IMAGE_SIZE
from testbed.learning import Learner
from testbed.learning.checkpoint import save_atomic
from testbed.learning.learning_config import LearningConfig
from testbed.records.store import FRAME_DTYPE, RunDataWriter

CASES = {
    "default twin trial, step 250 (4 arms)": dict(demos=375, transitions=400 + 1000,
                                                  labels=300, arms=4),
    "twin-scale, step 100 (100 arms)": dict(demos=200, transitions=200 + 10_000,
                                            labels=2_000, arms=100),
}


def _learner(demos: int, transitions: int, labels: int) -> Learner:
    rng = np.random.default_rng(0)
    learner = Learner(LearningConfig(), seed=0)

    def images(n: int) -> np.ndarray:
        return rng.integers(0, 256, (n, IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)

    learner.add_human(images(demos), rng.integers(0, 4, demos))
    for _ in range(0, labels, 4):  # the loop adds a step's teleop labels at a time
        learner.add_human(images(4), rng.integers(0, 4, 4))
    for k in range(0, transitions, 500):
        n = min(500, transitions - k)
        learner.add_transitions(images(n), rng.integers(0, 4, n), images(n),
                                rng.random(n) < 0.05, rng.random(n) < 0.1)
    learner.train_step()  # optimiser moments exist, as in a running trial
    return learner


def _before(learner: Learner) -> dict[str, Any]:
    """The old per-step snapshot: the whole state, data copied once."""
    state = learner.state_dict()
    fresh = {k: state.pop(k) for k in ("policy_data", "transitions")}
    return {**copy.deepcopy(state), **fresh}


def _time(take: Any, path: Path, repeat: int) -> tuple[float, float, int]:
    """Median snapshot seconds, median write seconds (fsynced), bytes."""
    snaps, writes = [], []
    for _ in range(repeat):
        s = time.perf_counter()
        state = take()
        m = time.perf_counter()
        save_atomic(state, path)
        e = time.perf_counter()
        snaps.append(m - s)
        writes.append(e - m)
    return statistics.median(snaps), statistics.median(writes), path.stat().st_size


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="bench-ckpt-", dir=Path.cwd()))
    try:
        for name, case in CASES.items():
            learner = _learner(case["demos"], case["transitions"], case["labels"])
            b_snap, b_write, b_size = _time(lambda lr=learner: _before(lr),
                                            work / "before.pt", args.repeat)
            held: list[dict[str, Any] | None] = [None]

            def after(lr: Learner = learner, held: list[Any] = held) -> dict[str, Any]:
                held[0] = lr.training_state(into=held[0])  # as CheckpointWriter does
                return held[0]

            a_snap, a_write, a_size = _time(after, work / "after.pt", args.repeat)
            store = RunDataWriter(work / name.split()[0], [f"r{i}" for i in range(case["arms"])])
            frames = np.zeros(case["arms"], FRAME_DTYPE)
            appends = []
            for t in range(args.repeat):
                frames["t"] = t
                s = time.perf_counter()
                store.append(frames)
                appends.append(time.perf_counter() - s)
            store.close()
            append = statistics.median(appends)
            before, after = b_snap + b_write, a_snap + a_write + append
            print(f"{name}:")
            print(f"  before: {b_size / 2**20:.1f} MB, snapshot {b_snap * 1e3:.0f} ms + write "
                  f"{b_write * 1e3:.0f} ms")
            print(f"  after:  {a_size / 2**20:.2f} MB, snapshot {a_snap * 1e3:.0f} ms + write "
                  f"{a_write * 1e3:.0f} ms; + data store append {append * 1e3:.1f} ms "
                  f"({case['arms'] * FRAME_DTYPE.itemsize / 2**20:.2f} MB)")
            print(f"  ratio before/after: size {b_size / a_size:.1f}x, time "
                  f"{before / after:.1f}x", flush=True)
    finally:
        import shutil

        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
