"""The forward pass of act at the paper's fleet size: eager, channels-last, torch.compile.

At N = 100 arms ``act`` runs 5 policy members and the safety critic (C.U.R.) on 100
images every step: about 8 GFLOP, the largest part of a loop step without training
(issue 13, item 2). Measured in this one run, each against the reference, eager
``Learner.act`` at the same thread count (ratio = reference / variant, > 1 is faster):

* ``actor eager``: the loop's act-only copy (``Learner.acting_copy()``), as the loop runs it;
* ``channels-last``: that copy with its weights in channels-last memory format (the
  input already is: ``ImageInput`` permutes without copying);
* ``compiled``: ``learning.compile_act = true`` (inductor); its one-off compile time is
  printed apart;

each at 1 thread and at every core. Interleaved repeats, medians.

    .venv/bin/python benchmarks/bench_act.py [--arms 100] [--repeats 15]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from testbed.core.types import IMAGE_SIZE
from testbed.learning import Learner
from testbed.learning.learning_config import LearningConfig


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arms", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args(argv)
    images = np.random.default_rng(0).integers(
        0, 256, (args.arms, IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
    learner = Learner(LearningConfig(), seed=0, read=("safety",))
    cores = learner.num_threads
    eager = learner.acting_copy()
    last = learner.acting_copy()
    with torch.no_grad():
        last._policy.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
        for net, _ in last._critics.values():
            net.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    compiled = Learner(learner.cfg.model_copy(update={"compile_act": True}), seed=0,
                       read=("safety",)).acting_copy()
    compiled.sync()
    start = time.perf_counter()
    compiled.act(images)
    print(f"{args.arms} images, 5 members + safety critic; {os.cpu_count()} cores; "
          f"torch.compile of the actor: {time.perf_counter() - start:.1f} s "
          f"(compiled: {compiled.compiled})", flush=True)
    variants: dict[str, Callable[[], object]] = {
        "Learner.act (reference)": lambda: learner.act(images),
        "actor eager": lambda: eager.act(images),
        "channels-last": lambda: last.act(images),
        "compiled": lambda: compiled.act(images),
    }
    for threads in sorted({1, cores}):
        torch.set_num_threads(threads)
        for fn in variants.values():
            fn()
        times: dict[str, list[float]] = {k: [] for k in variants}
        for r in range(args.repeats):
            order = list(variants) if r % 2 == 0 else list(reversed(variants))
            for k in order:
                s = time.perf_counter()
                variants[k]()
                times[k].append(time.perf_counter() - s)
        ref = statistics.median(times["Learner.act (reference)"])
        print(f"threads {threads} (load {os.getloadavg()[0]:.2f}):")
        for k, ts in times.items():
            med = statistics.median(ts)
            print(f"  {k:24s} median {med * 1e3:6.1f} ms (min {min(ts) * 1e3:6.1f}); "
                  f"ratio to the reference {ref / med:.2f}x")
    torch.set_num_threads(cores)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
