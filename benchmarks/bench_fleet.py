"""Does training really overlap the arms' execution? (issue 2's two targets)

(a) A twin trial's wall time divided by the time of the same number of training steps
    run alone (same learner, same data): target <= 1.25.
(b) With a simulated slow arm (each push takes as long as a training step), a step's
    wall time divided by max(arm time, training time): target <= 1.15.

Both use the real loop, real twin hosts in their agent processes, and real torch
training at the config's batch size. Run: ``.venv/bin/python benchmarks/bench_fleet.py``
(``--steps``, ``--batch`` to change the size).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from testbed.core.wrappers import HostsWrapper
from testbed.experiments.build import build_hosts
from testbed.experiments.fleet_config import FleetConfig, TrialConfig, default_twin_config
from testbed.experiments.hooks import TrialHooks
from testbed.experiments.learners import load_learner, pretrained_learner
from testbed.experiments.trial import TrialOptions, run_trial
from testbed.fleet.algorithms import ALGORITHMS
from testbed.learning.learning_config import LearningConfig


class SlowHosts(HostsWrapper):
    """The real hosts, but every execute takes at least ``delay`` seconds (a slow arm)."""

    def __init__(self, hosts: Any, delay: float) -> None:
        super().__init__(hosts)
        self.delay = delay
        self.arm_times: list[float] = []

    def execute(self, pushes: Mapping[str, int], resets: Sequence[str]) -> Any:
        t0 = time.perf_counter()
        out = self.hosts.execute(pushes, resets)
        left = self.delay - (time.perf_counter() - t0)
        if left > 0:
            time.sleep(left)
        self.arm_times.append(time.perf_counter() - t0)
        return out


class _Tick(TrialHooks):
    def __init__(self, tick: Callable[[Any], None]) -> None:
        self.tick = tick

    def on_step(self, outcome: Any) -> None:
        self.tick(outcome)


def _cfg(batch: int, steps: int) -> FleetConfig:
    base = default_twin_config()
    return base.model_copy(
        update={
            "learning": LearningConfig(batch_size=batch, pretrain_steps=20, demos=120,
                                       critic_transitions=120),
            "trial": TrialConfig(steps=steps),
        }
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--batch", type=int, default=256)
    args = ap.parse_args()
    cfg = _cfg(args.batch, args.steps)
    out = Path(tempfile.mkdtemp(prefix="bench-fleet-"))
    from testbed.experiments.scripted_humans import ScriptedHumans

    _, ckpt = pretrained_learner(cfg, ScriptedHumans(), out, None)

    # Reference: the same number of training steps alone, of the parts C.U.R. trains.
    learner = load_learner(cfg, ckpt)
    cur = ALGORITHMS["cur"]
    learner.set_parts(train=cur.train_parts, read=cur.critics)
    learner.train_step()
    t0 = time.perf_counter()
    times = []
    for _ in range(args.steps):
        s = time.perf_counter()
        learner.train_step()
        times.append(time.perf_counter() - s)
    train_alone = time.perf_counter() - t0
    train_step = statistics.median(times)

    # (a) the trial.
    opts = TrialOptions(algorithm="cur", steps=args.steps, seed=0, out=str(out),
                        humans="scripted", policy=str(ckpt))
    step_times: list[float] = []
    last = [time.perf_counter()]

    def tick(_: Any) -> None:
        now = time.perf_counter()
        step_times.append(now - last[0])
        last[0] = now

    t0 = time.perf_counter()
    run_trial(cfg, opts, hooks=_Tick(tick))
    trial_wall = time.perf_counter() - t0
    loop_wall = sum(step_times[1:]) * args.steps / max(len(step_times) - 1, 1)
    print(f"training step alone: median {train_step * 1e3:.0f} ms (batch {args.batch}, "
          f"{cfg.learning.ensemble_size} members)")
    print(f"(a) {args.steps} training steps alone: {train_alone:.2f} s; trial loop: "
          f"{loop_wall:.2f} s (whole trial incl. startup {trial_wall:.2f} s)")
    print(f"(a) ratio trial / training alone = {loop_wall / train_alone:.3f}  (target <= 1.25)")

    # (b) a slow arm: each push takes as long as a training step.
    hosts = SlowHosts(build_hosts(cfg, 1), delay=train_step)
    hosts.hosts.start()
    step_times.clear()
    last[0] = time.perf_counter()
    opts_b = TrialOptions(algorithm="cur", steps=args.steps, seed=1, out=str(out),
                          humans="scripted", policy=str(ckpt))
    try:
        run_trial(cfg, opts_b, hooks=_Tick(tick), hosts=hosts)
    finally:
        hosts.rest()
        hosts.close()
    step = statistics.median(step_times[1:])
    arm = statistics.median(hosts.arm_times)
    ref = max(arm, train_step)
    print(f"(b) step wall median {step * 1e3:.0f} ms; arm {arm * 1e3:.0f} ms; "
          f"training {train_step * 1e3:.0f} ms")
    print(f"(b) ratio step / max(arm, training) = {step / ref:.3f}  (target <= 1.15)")


if __name__ == "__main__":
    main()
