"""Train only what the algorithm reads (issue 13): one training step, new vs today's.

Today's step (before issue 13) trained every part whatever the algorithm: the policy
(5 members), pi(s') for the critics' targets (the 5 members' forward pass on the next
images), the safety critic AND the goal critic. Now a learner trains what its
algorithm reads (``AlgorithmSpec.train_parts``): C.U.R. the policy and the safety
critic (pi(s') still computed, once), Fleet-EnsembleDAgger the policy alone (no pi(s'),
no critic). ``legacy_step`` below is today's ``_one_step`` verbatim, run on the same
learner internals; the benchmark first checks it gives bit-identical weights to the new
code with every part on (so it is a faithful "today").

Today's code also ran torch on half the cores (1 thread on this 2-core machine, with
OpenMP's spinning wait); the new default is every core with a passive wait
(``testbed/learning/runtime.py``). So each algorithm is timed twice:

1. parts only: new step vs ``legacy_step``, both at the new thread count;
2. the whole change: new step at the new thread count vs ``legacy_step`` at today's
   (``--old-threads``, default half the cores). OpenMP's wait policy is fixed for the
   process when torch loads; at 1 thread it does not matter (no worker waits).

Both sides are timed in the same run, interleaved (new, old, old, new, ...: the order
flips every repeat so that a load spike from other processes hits both alike); medians
and minima are printed, and the ratio of the medians (old / new: how many times
faster). ``act`` for one step's 4 images likewise (the critics nobody reads are skipped).

    .venv/bin/python benchmarks/bench_train_parts.py [--repeats 9] [--members 5] [--batch 256]
        [--old-threads N]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_training import fill

from testbed.fleet.algorithms import ALGORITHMS
from testbed.learning import Learner
from testbed.learning.critics import CriticBatch
from testbed.learning.learning_config import LearningConfig
from testbed.learning.policy import ensemble_signals


def legacy_step(self: Learner) -> dict[str, float]:
    """Today's ``Learner._one_step`` (before issue 13): policy + safety + goal, one
    shared pi(s') forward pass, whatever the algorithm reads."""
    losses: dict[str, float] = {}
    if len(self.policy_data):
        losses["policy_loss"] = self._policy_update()
    if len(self.transitions):
        index = self.transitions.sample_indices(self.cfg.batch_size, self._sampler)
        b = {k: v.to(self.device) for k, v in self.transitions.gather(index).items()}
        with torch.no_grad():
            next_actions = ensemble_signals(self.policy(b["next_images"]))["actions"]
        violation = b["violation"].float()
        success = b["success"].float()
        safety = self.safety.update(CriticBatch(
            b["images"], b["actions"], b["next_images"], next_actions,
            reward=violation, done=violation,
        ))
        goal = self.goal.update(CriticBatch(
            b["images"], b["actions"], b["next_images"], next_actions,
            reward=success, done=torch.maximum(success, violation),
        ))
        self.critic_updates += 1
        losses.update({"safety_loss": safety, "goal_loss": goal})
    return losses


def weights(learner: Learner) -> list[torch.Tensor]:
    mods = [learner.policy, learner.safety.net, learner.safety.target, learner.goal.net,
            learner.goal.target]
    return [p.detach().clone() for m in mods for p in m.parameters()]


def at_threads(threads: int, fn: Callable[[], object]) -> Callable[[], object]:
    """``fn`` run with torch at ``threads`` intra-op threads (set before each call: the
    two sides of a comparison alternate in one process)."""
    def call() -> object:
        torch.set_num_threads(threads)
        return fn()
    return call


def timed(fn: Callable[[], object]) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def interleaved(new: Callable[[], object], old: Callable[[], object], repeats: int
                ) -> tuple[list[float], list[float]]:
    ts_new: list[float] = []
    ts_old: list[float] = []
    for r in range(repeats):
        if r % 2 == 0:
            ts_new.append(timed(new))
            ts_old.append(timed(old))
        else:
            ts_old.append(timed(old))
            ts_new.append(timed(new))
    return ts_new, ts_old


def report(label: str, ts_new: list[float], ts_old: list[float]) -> float:
    med_new, med_old = statistics.median(ts_new), statistics.median(ts_old)
    ratio = med_old / med_new
    print(f"{label}: new median {med_new * 1e3:7.1f} ms (min {min(ts_new) * 1e3:7.1f}); "
          f"today's median {med_old * 1e3:7.1f} ms (min {min(ts_old) * 1e3:7.1f}); "
          f"today / new = {ratio:.2f}x (min/min {min(ts_old) / min(ts_new):.2f}x)")
    return ratio


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--members", type=int, default=5)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--device", choices=["auto", "cpu", "cuda"], default="auto")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--old-threads", type=int, default=None,
                        help="today's torch threads (default: half the cores, at least 1)")
    args = parser.parse_args(argv)
    cfg = LearningConfig(ensemble_size=args.members, batch_size=args.batch, device=args.device)

    # "today" is faithful: legacy_step == the new step with every part on, bit for bit
    a, b = Learner(cfg, args.seed), Learner(cfg, args.seed)
    fill(a, args.seed)
    fill(b, args.seed)
    legacy_step(a)
    b.train_step()
    faithful = all(torch.equal(x, y) for x, y in zip(weights(a), weights(b), strict=True))
    print(f"device {a.device}, torch threads {a.num_threads}, impl {a.impl}, "
          f"{args.members} members x batch {args.batch}; legacy step == new step with "
          f"every part: {faithful}")
    if not faithful:
        print("legacy_step no longer matches the learner's full step: update it")
        return 1
    del a, b

    images = np.zeros(0)
    new_threads = Learner(cfg, args.seed).num_threads
    old_threads = args.old_threads or max(1, (os.cpu_count() or 2) // 2)
    print(f"threads: new {new_threads} (OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY')}), "
          f"today's {old_threads}")
    ratios: dict[str, float] = {}
    whole: dict[str, float] = {}
    for name in ("cur", "fleet-ed"):
        spec = ALGORITHMS[name]
        new = Learner(cfg, args.seed, train=spec.train_parts, read=spec.critics)
        old = Learner(cfg, args.seed)
        for learner in (new, old):
            images = fill(learner, args.seed)
        new_step = at_threads(new_threads, new.train_step)
        old_step = partial(legacy_step, old)
        new_step()  # warm-up: oneDNN primitives, allocator
        at_threads(old_threads, old_step)()
        at_threads(new_threads, old_step)()
        parts = ", ".join(sorted(spec.train_parts))
        ts_new, ts_old = interleaved(new_step, at_threads(new_threads, old_step),
                                     args.repeats)
        ratios[name] = report(f"{name:8s} 1. parts: train step ({parts}) vs today's "
                              f"(policy, safety, goal), both at {new_threads} threads",
                              ts_new, ts_old)
        ts_new, ts_old = interleaved(new_step, at_threads(old_threads, old_step),
                                     args.repeats)
        whole[name] = report(f"{name:8s} 2. whole: train step ({parts}) at {new_threads} "
                             f"threads vs today's at {old_threads}", ts_new, ts_old)
        torch.set_num_threads(new_threads)
        batch = images[:4]
        act_new, act_old = interleaved(partial(new.act, batch), partial(old.act, batch),
                                       max(20, args.repeats))
        report(f"{name:8s} act, 4 images (critics read: "
               f"{', '.join(sorted(spec.critics)) or 'none'}) vs today's (both)",
               act_new, act_old)
    print("speed-up of one training step (median, today / new), parts only: "
          + ", ".join(f"{k} {v:.2f}x" for k, v in ratios.items()))
    print("speed-up of one training step (median, today / new), parts and threads "
          "(target >= 2x): " + ", ".join(f"{k} {v:.2f}x" for k, v in whole.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
