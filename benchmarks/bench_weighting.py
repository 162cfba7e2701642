"""Learning by class (issue 30): one training step, ``intervention`` vs ``uniform``.

The target: a training step costs no more than 1.05x today's. Both learners hold the
data of the end of a 250-step, 4-arm C.U.R. trial (375 demonstrations, 400 human labels,
1000 transitions); the ``intervention`` one holds the robot's own pushes too (``--robot``,
default 600: what the twin's runs give it at the default class weights), which is what it
trains on, so its multinomial runs over more samples. Each member draws its minibatch in
proportion to bootstrap weight x class weight: a gather and a multiply over the samples
per step, against a forward and backward pass of 5 members on the minibatch.

Both are timed in the same run, interleaved (the order flips every repeat, so a load spike
hits both alike); medians, minima and the ratio of the medians (intervention / uniform)
are printed for the parts C.U.R. trains (policy + safety critic) at the twin protocol's
batch (64) and the paper's (256).

    .venv/bin/python benchmarks/bench_weighting.py [--repeats 15] [--robot 600]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from testbed.core.types import EpisodeOutcome, FrameClass
from testbed.learning import Learner
from testbed.learning.learning_config import LearningConfig


def _learner(weighting: str, batch: int, robot: int, seed: int) -> Learner:
    cfg = LearningConfig(batch_size=batch, weighting=weighting)  # type: ignore[arg-type]
    learner = Learner(cfg, seed=seed, train={"policy", "safety"}, read={"safety"})
    rng = np.random.default_rng(seed)
    images = rng.integers(0, 256, (1375, 64, 64, 3), dtype=np.uint8)
    actions = rng.integers(0, 4, 1375)
    learner.add_human(images[:375], actions[:375])
    for k in range(375, 775, 4):  # labels arrive a step's few at a time
        learner.add_human(images[k : k + 4], actions[k : k + 4], labellers=np.zeros(4, np.int64))
    for k in range(775, 775 + robot, 6):  # an ended episode's pushes at a time
        n = min(6, 775 + robot - k)
        learner.add_robot(images[k : k + n], actions[k : k + n],
                          np.full(n, FrameClass.ROBOT), np.full(n, EpisodeOutcome.SUCCESS))
    idx = rng.integers(0, 775, 1000)
    learner.add_transitions(images[idx], actions[idx], images[(idx + 1) % 775],
                            rng.random(1000) < 0.05, rng.random(1000) < 0.05)
    return learner


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--robot", type=int, default=600)
    args = parser.parse_args(argv)
    worst = 0.0
    for batch in (64, 256):
        uniform = _learner("uniform", batch, args.robot, 0)
        weighted = _learner("intervention", batch, args.robot, 0)
        print(f"batch {batch}: uniform {uniform.data_sizes()['policy']} samples, "
              f"intervention {weighted.data_sizes()['policy']}")
        for learner in (uniform, weighted):  # warm up
            learner.train_step()
        times: dict[str, list[float]] = {"uniform": [], "intervention": []}
        for r in range(args.repeats):
            pair = [("uniform", uniform), ("intervention", weighted)]
            for name, learner in pair if r % 2 == 0 else pair[::-1]:
                start = time.perf_counter()
                learner.train_step()
                times[name].append(time.perf_counter() - start)
        for name, ts in times.items():
            print(f"  {name:12s} min {min(ts) * 1e3:7.1f} ms   "
                  f"median {statistics.median(ts) * 1e3:7.1f} ms")
        ratio = statistics.median(times["intervention"]) / statistics.median(times["uniform"])
        floor = min(times["intervention"]) / min(times["uniform"])
        worst = max(worst, ratio)
        print(f"  ratio intervention / uniform: medians {ratio:.3f}, minima {floor:.3f}  "
              "(target <= 1.05; minima: the cost without other processes' load)")
    print(f"worst ratio: {worst:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
