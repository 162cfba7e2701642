"""The paper's fleet size: one loop step at N = 100 arms, M = 10 humans (issue 13, item 4).

``protocols/twin-scale.toml``'s fleet (50 twin cells of 2 arms, one agent process per
cell, 10 scripted humans, C.U.R., batch 256, 5 members), driven by the real
``FleetLoop`` as ``run_trial`` builds it (records fsynced, a checkpoint per step).
Printed, all measured in this one run:

1. The loop step WITHOUT training: C.U.R. with its real priority, allocator, humans,
   data and records, but a learner whose ``train_step`` does nothing (``NoTraining``:
   act and the data calls go to the real learner). Median step against the 150 ms
   target (ratio = step / target), and where the time goes: observe, act, allocate,
   humans, execute, store (the run's data store: 100 frames, fsynced), log (steps.jsonl),
   data (the learner's), checkpoint snapshot, the rest (the loop's own Python).
2. The loop step WITH training (the real ``train_step`` in the loop's thread) against
   one training step alone, same learner and data, measured before and after it:
   ratio = step / training step (target <= 1.2).

The machine may be shared: the load average (``os.getloadavg``) is printed at each
phase; the start-up of the 50 agents is timed apart and warm-up steps are dropped.

    .venv/bin/python benchmarks/bench_scale.py [--steps 20] [--warmup 5] [--train 8]
        [--compile-act on|off] [--no-checkpoint]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from testbed.experiments.build import build_hosts
from testbed.experiments.checkpointer import CheckpointWriter
from testbed.experiments.fleet_config import FleetConfig, load_fleet
from testbed.experiments.learners import pretrained_learner
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.fleet.algorithms import get_algorithm
from testbed.fleet.loop import FleetLoop
from testbed.records.steps import RunWriter
from testbed.records.store import RunDataWriter

PROTOCOL = Path(__file__).resolve().parents[1] / "protocols" / "twin-scale.toml"
TARGET_MS = 150.0
TARGET_RATIO = 1.2
SEED = 0


class Splits:
    """Wall time per named part of the current step (seconds)."""

    def __init__(self) -> None:
        self.now: dict[str, float] = defaultdict(float)

    def timed(self, name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def call(*a: Any, **k: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                self.now[name] += time.perf_counter() - t0

        return call

    def take(self) -> dict[str, float]:
        out, self.now = dict(self.now), defaultdict(float)
        return out


class TimedHosts:
    def __init__(self, hosts: Any, splits: Splits) -> None:
        self.robot_names = hosts.robot_names
        self.observe = splits.timed("observe", hosts.observe)
        self.execute = splits.timed("execute", hosts.execute)


class TimedHumans:
    def __init__(self, humans: Any, splits: Splits) -> None:
        self.act = splits.timed("humans", humans.act)
        self.show = humans.show
        self.close = humans.close


class NoTraining:
    """The real learner (its acting copy, compiled as the protocol says, and the data
    calls timed), but ``train_step`` does nothing."""

    def __init__(self, learner: Any, splits: Splits) -> None:
        self.act = learner.act  # not called: the loop acts on the copy, timed in run_loop
        self.acting_copy = learner.acting_copy
        self.add_human = splits.timed("data", learner.add_human)
        self.add_transitions = splits.timed("data", learner.add_transitions)

    def train_step(self) -> dict[str, float]:
        return {}


class TimedAlgorithm:
    """The algorithm (priority + allocator); ``step`` timed as "allocate"."""

    def __init__(self, algorithm: Any, splits: Splits) -> None:
        self._algorithm = algorithm
        self.step = splits.timed("allocate", algorithm.step)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._algorithm, name)


class TimedWriter:
    def __init__(self, writer: RunWriter, splits: Splits) -> None:
        self.write_step = splits.timed("log", writer.write_step)


def _config(pretrain_steps: int, compile_act: bool | None) -> FleetConfig:
    """The protocol's fleet; theta_0 smaller than the protocol's (the step does not
    depend on how good the policy is, only on the trial's hyperparameters, kept)."""
    cfg = load_fleet(PROTOCOL)
    update: dict[str, Any] = {
        "pretrain_steps": pretrain_steps, "demos": 200, "critic_transitions": 200}
    if compile_act is not None:
        update["compile_act"] = compile_act
    learning = cfg.learning.model_copy(update=update)
    return cfg.model_copy(update={"learning": learning})


def run_loop(cfg: FleetConfig, hosts: Any, learner: Any, run_dir: Path, *, train: bool,
             warmup: int, steps: int, t0: int, checkpoint_every_step: bool = True,
             ) -> tuple[list[float], list[dict[str, float]]]:
    """``warmup + steps`` loop steps as run_trial runs them; the measured steps' wall
    times and splits."""
    splits = Splits()
    n = len(cfg.robot_names)
    algorithm = get_algorithm("cur", cfg.algorithm, n, cfg.humans.count, SEED)
    run_dir.mkdir(parents=True, exist_ok=True)
    writer = RunWriter(run_dir)
    data = RunDataWriter(run_dir, cfg.robot_names)
    data.steps = t0  # phase 2 goes on counting from phase 1, in a folder of its own
    data.append = splits.timed("store", data.append)  # type: ignore[method-assign]
    checkpoints = CheckpointWriter(run_dir)
    snapshot = splits.timed("checkpoint", checkpoints.submit)

    def checkpoint(step: int) -> None:
        snapshot(step, learner, {"algorithm": algorithm.state_dict()})

    # The loop acts on the learner's acting copy (as in run_trial): beside the training
    # step when there is one; act is timed on that copy.
    loop = FleetLoop(hosts=TimedHosts(hosts, splits), humans=TimedHumans(ScriptedHumans(),
                     splits), learner=learner if train else NoTraining(learner, splits),
                     algorithm=TimedAlgorithm(algorithm, splits),  # type: ignore[arg-type]
                     writer=TimedWriter(writer, splits),  # type: ignore[arg-type]
                     steps=t0 + warmup + steps, num_humans=cfg.humans.count,
                     t_T=cfg.algorithm.t_T, t_R=cfg.algorithm.t_R,
                     after_step=checkpoint if checkpoint_every_step else None,
                     data=data)
    assert loop._actor is not None, "the loop should act on the learner's acting copy"
    loop._actor.act = splits.timed("act", loop._actor.act)  # type: ignore[method-assign]
    walls: list[float] = []
    parts: list[dict[str, float]] = []
    try:
        for t in range(t0, t0 + warmup + steps):
            s = time.perf_counter()
            loop.step(t)
            wall = time.perf_counter() - s
            split = splits.take()
            if t >= t0 + warmup:
                walls.append(wall)
                parts.append(split | {"rest": wall - sum(split.values())})
    finally:
        checkpoints.wait()
        loop.close()
        writer.close()
        data.close()
    return walls, parts


def train_alone(learner: Any, k: int) -> list[float]:
    times = []
    for _ in range(k):
        s = time.perf_counter()
        learner.train_step()
        times.append(time.perf_counter() - s)
    return times


def _load() -> str:
    return "/".join(f"{x:.2f}" for x in os.getloadavg())


def _parts_line(parts: Sequence[Mapping[str, float]]) -> str:
    names = ["observe", "act", "allocate", "humans", "execute", "store", "log", "data",
             "checkpoint", "rest"]
    med = {k: statistics.median(p.get(k, 0.0) for p in parts) * 1e3 for k in names}
    return ", ".join(f"{k} {v:.1f}" for k, v in med.items())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20, help="measured loop steps per phase")
    ap.add_argument("--warmup", type=int, default=5, help="loop steps dropped per phase")
    ap.add_argument("--train", type=int, default=8,
                    help="training steps alone, before and after the loop with training")
    ap.add_argument("--pretrain-steps", type=int, default=20)
    ap.add_argument("--no-checkpoint", action="store_true",
                    help="no per-step checkpoint (to see what its background write costs)")
    ap.add_argument("--compile-act", choices=["on", "off"], default=None,
                    help="override the protocol's learning.compile_act")
    ap.add_argument("--out", default=None, help="work folder (keeps theta_0 cached); "
                    "default: a fresh temp folder")
    args = ap.parse_args(argv)
    cfg = _config(args.pretrain_steps,
                  None if args.compile_act is None else args.compile_act == "on")
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench-scale-"))
    n, m = len(cfg.robot_names), cfg.humans.count
    print(f"fleet: {len(cfg.hosts)} twin hosts (one agent process each) = {n} arms, "
          f"{m} scripted humans, C.U.R., batch {cfg.learning.batch_size}, "
          f"{cfg.learning.ensemble_size} members, compile_act "
          f"{cfg.learning.compile_act}; {os.cpu_count()} cores; load {_load()}", flush=True)

    hosts = build_hosts(cfg, SEED)
    s = time.perf_counter()
    hosts.start()
    print(f"start-up of {len(cfg.hosts)} agents: {time.perf_counter() - s:.1f} s", flush=True)
    try:
        s = time.perf_counter()
        learner, _ = pretrained_learner(cfg, ScriptedHumans(), out, None, hosts=hosts,
                                        trial_seed=SEED)
        print(f"theta_0 (cached in {out}): {time.perf_counter() - s:.1f} s", flush=True)
        algorithm = get_algorithm("cur", cfg.algorithm, n, m, SEED)
        spec = algorithm.spec
        if hasattr(learner, "set_parts") and hasattr(spec, "train_parts"):
            learner.set_parts(train=spec.train_parts, read=spec.critics)
        learner.reseed(SEED)

        # 1. without training
        load1 = _load()
        walls, parts = run_loop(cfg, hosts, learner, out / "no-training", train=False,
                                warmup=args.warmup, steps=args.steps, t0=0,
                                checkpoint_every_step=not args.no_checkpoint)
        step = statistics.median(walls) * 1e3
        print(f"1. loop step WITHOUT training (median of {args.steps}, load {load1}): "
              f"{step:.0f} ms; ratio to the {TARGET_MS:.0f} ms target {step / TARGET_MS:.2f}")
        print(f"   parts (median ms): {_parts_line(parts)}")
        no_act = statistics.median(
            w - p.get("act", 0.0) for w, p in zip(walls, parts, strict=True)) * 1e3
        print(f"   the step without act (the learner's forward pass): {no_act:.0f} ms; "
              f"ratio {no_act / TARGET_MS:.2f}", flush=True)

        # 2. with training, against the training step alone (before and after)
        learner.train_step()  # warm
        alone = train_alone(learner, args.train)
        load2 = _load()
        walls, parts = run_loop(cfg, hosts, learner, out / "training", train=True,
                                warmup=args.warmup, steps=args.steps,
                                t0=args.warmup + args.steps,
                                checkpoint_every_step=not args.no_checkpoint)
        alone += train_alone(learner, args.train)
        train = statistics.median(alone) * 1e3
        step = statistics.median(walls) * 1e3
        print(f"2. training step alone (median of {len(alone)}): {train:.0f} ms; loop step "
              f"WITH training (median of {args.steps}, load {load2}): {step:.0f} ms")
        print(f"   ratio step / training step = {step / train:.3f} (target <= {TARGET_RATIO})")
        print(f"   parts (median ms; act runs beside the training step; rest includes "
              f"the data calls and waiting for the training): "
              f"{_parts_line(parts)}")
        print(f"load at the end: {_load()}")
    finally:
        hosts.rest()
        hosts.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
