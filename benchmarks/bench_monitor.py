"""What the failure monitor adds to a fleet step at the paper's size (issue 36, item 6:
at most 5 % at N = 100 arms).

The monitor adds three things to a step, each measured here in this one run against the
same work without it (interleaved repeats, medians; the real learner at batch 256, 5
members, the safety critic, 2000 labelled images and 3000 transitions):

1. the training step: ``Learner._update_features`` (64 labelled images through each
   member's trunk, the running mean and covariance) after every ``FEATURE_EVERY``-th
   policy update: timed apart, interleaved with the training step, its share per step
   added;
2. ``act`` on 100 images: the trunk features kept and each image's Mahalanobis distance
   (``FeatureDensity.score``); in the loop act runs beside the training step, so this
   part costs the step nothing while act is shorter than training, and is printed apart;
3. the allocation: ``MonitorPriority.keys`` + ``observe`` (its alarm ready, 200
   successful episodes), on ``ood_u`` and on the failure head
   (``protocols/heads/twin-baseline.json``: 64 trunk features and risk per arm; the
   features come with act's forward pass), against C.U.R.'s ``OrderedPriority.keys``.

The step's ratio: (training with the feature update + the monitor's keys and observe) /
(training without it + C.U.R.'s keys), the loop's critical path at N = 100 (act overlaps
training there: docs/notes/fleet.md). Target <= 1.05.

    .venv/bin/python benchmarks/bench_monitor.py [--repeats 15]
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

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch

from testbed.core.types import IMAGE_SIZE, NUM_ACTIONS
from testbed.fleet.monitor_priority import MonitorPriority
from testbed.fleet.priorities import OrderedPriority, PrioritySignals
from testbed.learning import Learner
from testbed.learning.learner import FEATURE_EVERY
from testbed.learning.learning_config import LearningConfig
from testbed.monitor.failure_head import FailureHead
from testbed.records.store import FRAME_DTYPE, MODES

ARMS = 100
TARGET = 1.05
HEAD = Path(__file__).resolve().parents[1] / "protocols" / "heads" / "twin-baseline.json"


def timed(fn: Callable[[], object]) -> float:
    s = time.perf_counter()
    fn()
    return time.perf_counter() - s


def interleaved(variants: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Median seconds of each variant, run in alternating order after one warm-up each."""
    for fn in variants.values():
        fn()
    times: dict[str, list[float]] = {k: [] for k in variants}
    for r in range(repeats):
        for k in (list(variants) if r % 2 == 0 else list(reversed(variants))):
            times[k].append(timed(variants[k]))
    return {k: statistics.median(v) for k, v in times.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    learner = Learner(LearningConfig(), seed=0, train=("policy", "safety"), read=("safety",))
    images = rng.integers(0, 256, (2000, IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
    learner.add_human(images, rng.integers(0, NUM_ACTIONS, 2000))
    learner.add_transitions(images[:1500], rng.integers(0, NUM_ACTIONS, 1500), images[500:],
                            rng.random(1500) < 0.1, rng.random(1500) < 0.1)
    fleet = images[:ARMS]
    update = learner._update_features

    def train_plain() -> None:
        learner._update_features = lambda: None  # type: ignore[method-assign]
        try:
            learner.train_step()
        finally:
            learner._update_features = update  # type: ignore[method-assign]

    def feature_update() -> None:
        learner.policy_updates -= learner.policy_updates % FEATURE_EVERY  # one that runs
        update()

    parts = interleaved({"train": train_plain, "features": feature_update}, args.repeats)
    train = {"without": parts["train"],
             "with": parts["train"] + parts["features"] / FEATURE_EVERY}
    actor = learner.acting_copy()
    plain_actor = learner.acting_copy()
    plain_actor._features = None
    act = interleaved({"with": lambda: actor.act(fleet),
                       "without": lambda: plain_actor.act(fleet)}, args.repeats)

    sig = PrioritySignals(t=100, violating=rng.random(ARMS) < 0.05,
                          uncertainty=rng.random(ARMS), risk=rng.random(ARMS),
                          novelty=rng.random(ARMS), ood=rng.random(ARMS) + 0.5,
                          features=rng.random((ARMS, 64)))
    monitor = MonitorPriority(ARMS, score="ood_u", alpha=0.05, window=200, u_hat=0.2,
                              r_hat=0.5)
    with_head = MonitorPriority(ARMS, score="fail_head", alpha=0.05, window=200, u_hat=0.2,
                                r_hat=0.5, head=FailureHead.load(HEAD))
    frames = np.zeros(ARMS, FRAME_DTYPE)
    frames["mode"] = MODES.index("autonomous")
    frames["action"] = 1
    frames["observed"] = True
    for _ in range(200):  # 200 successful episodes: the alarm is ready, its window full
        for m in (monitor, with_head):
            m.keys(sig)
            frames["success"] = True
            m.observe(frames)
    frames["success"] = rng.random(ARMS) < 0.1
    cur = OrderedPriority("cur", ARMS, initial_period=10, u_hat=0.2, r_hat=0.5)

    def monitor_step() -> None:
        monitor.keys(sig)
        monitor.observe(frames)

    def head_step() -> None:
        with_head.keys(sig)
        with_head.observe(frames)

    keys = interleaved({"with": monitor_step, "head": head_step,
                        "without": lambda: cur.keys(sig)}, args.repeats * 20)
    with_step = train["with"] + keys["with"]
    without_step = train["without"] + keys["without"]
    print(f"{os.cpu_count()} cores, {torch.get_num_threads()} torch threads, "
          f"load {os.getloadavg()[0]:.2f}; N = {ARMS} arms, batch 256, 5 members")
    print(f"training step: {1000 * train['without']:.0f} ms; the feature update "
          f"{1000 * parts['features']:.1f} ms every {FEATURE_EVERY} updates: "
          f"+{1000 * parts['features'] / FEATURE_EVERY:.1f} ms a step")
    print(f"act on {ARMS} images (beside training in the loop): {1000 * act['with']:.1f} ms "
          f"with ood, {1000 * act['without']:.1f} ms without "
          f"(+{1000 * (act['with'] - act['without']):.1f} ms)")
    print(f"allocation: monitor keys + observe {1000 * keys['with']:.2f} ms (ood_u), "
          f"{1000 * keys['head']:.2f} ms (the failure head), C.U.R. keys "
          f"{1000 * keys['without']:.2f} ms")
    ratio = with_step / without_step
    head_ratio = (train["with"] + keys["head"]) / without_step
    print(f"step ratio (training + allocation, with / without the monitor): {ratio:.3f} "
          f"(ood_u), {head_ratio:.3f} (the failure head) (target <= {TARGET}: "
          f"{'met' if max(ratio, head_ratio) <= TARGET else 'NOT met'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
