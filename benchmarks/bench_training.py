"""How long does the learner's training step take, as a Python loop and as torch.func.vmap?

Why this exists: training runs once per fleet timestep beside the arms' execution, and
the paper's batch (256) times 5 members is the bulk of the controller's CPU time. The
ensemble can run its members one after the other (``loop``) or vectorised over their
stacked parameters (``vmap``); which is faster depends on the device, and
``testbed/learning/runtime.py::resolve_impl`` picks by these figures. Also printed:
the whole ``train_step`` (policy + safety critic + goal critic, with pi(s') for the
critics' targets) and ``act`` for one step's 4 images.

Timings are interleaved (loop, vmap, loop, ...) so that load from other processes hits
both alike; min and median are printed. On a shared 2-core machine re-run and compare.

    .venv/bin/python benchmarks/bench_training.py [--repeats 7] [--members 5] [--batch 256]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from testbed.learning import Learner
from testbed.learning.learning_config import LearningConfig


def fill(learner: Learner, seed: int) -> np.ndarray:
    """375 labelled images (the paper's offline set) and 1000 transitions; returns images."""
    rng = np.random.default_rng(seed)
    images = rng.integers(0, 256, (375, 64, 64, 3), dtype=np.uint8)
    actions = rng.integers(0, 4, 375)
    learner.add_human(images, actions)
    idx = rng.integers(0, 375, 1000)
    learner.add_transitions(images[idx], actions[idx], images[(idx + 1) % 375],
                            rng.random(1000) < 0.05, rng.random(1000) < 0.05)
    return images


def timed(fn: Callable[[], object]) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def fmt(ts: list[float]) -> str:
    return f"min {min(ts) * 1e3:7.1f} ms   median {statistics.median(ts) * 1e3:7.1f} ms"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--members", type=int, default=5)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--device", choices=["auto", "cpu", "cuda"], default="auto")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    cfg = LearningConfig(ensemble_size=args.members, batch_size=args.batch, device=args.device)

    learners = {impl: Learner(cfg, args.seed, impl=impl) for impl in ("loop", "vmap")}
    images = np.zeros(0)
    for learner in learners.values():
        images = fill(learner, args.seed)
    auto = Learner(cfg, args.seed)
    fill(auto, args.seed)
    print(f"device {auto.device}, torch threads {auto.num_threads}, "
          f"{args.members} members x batch {args.batch}, 64x64x3; auto picks '{auto.impl}'")

    # warm-up: oneDNN primitive creation, allocator, vmap tracing
    for learner in (*learners.values(), auto):
        learner._policy_update()
        learner.train_step()

    policy: dict[str, list[float]] = {impl: [] for impl in learners}
    for _ in range(args.repeats):
        for impl, learner in learners.items():
            policy[impl].append(timed(learner._policy_update))
    for impl, ts in policy.items():
        print(f"policy step ({impl:4s}, 1 Adam step, all members): {fmt(ts)}")
    ratio_min = min(policy["vmap"]) / min(policy["loop"])
    ratio_med = statistics.median(policy["vmap"]) / statistics.median(policy["loop"])
    faster = "loop" if ratio_med > 1 else "vmap"
    print(f"vmap / loop: {ratio_min:.2f}x (min), {ratio_med:.2f}x (median) -> {faster} is "
          f"faster on {auto.device.type}")

    full = [timed(auto.train_step) for _ in range(args.repeats)]
    print(f"train_step ({auto.impl}, policy + safety + goal critics): {fmt(full)}")
    act = [timed(lambda: auto.act(images[:4])) for _ in range(max(20, args.repeats))]
    print(f"act (4 images: actions, uncertainty, risk, goal risk, novelty): {fmt(act)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
