"""How fast is a twin fleet? One timestep of 50 twin cells (100 arms), and images/s.

Why this exists: twin mode and the paper-scale simulations (N = 100 arms) run the
PyBullet cells inside every timestep, so a timestep of the whole fleet -- every arm
pushes, then every cell renders and reports its arms' images, ground truth and expert
choice -- must stay within the target (150 ms on the 2-core dev machine) without
training. Printed:

1. Timestep of 50 cells in this one process (push + observe + expert, serially), and
   the same 50 cells split over 2 worker processes (as the fleet runs them: one agent
   process per host), against the 150 ms target (ratio = time / target).
2. Per cell: observed pictures per second (render + crops + goal discs, 2 arm images
   each) against the bare ``getCameraImage`` of the same camera and world in the same
   run (ratio), and for reference a bare render with a table mesh in view (why the twin
   paints the table in software).

    .venv/bin/python benchmarks/bench_twin.py [--cells 50] [--steps 20] [--repeats 3]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import statistics
import sys
import time
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np
import pybullet as pb

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim_twin import TwinCell

TARGET_MS = 150.0


def _push_all(cells: list[TwinCell], rng: np.random.Generator) -> None:
    """Every arm pushes: mostly the expert, sometimes at random, so violations and hard
    resets happen too."""
    for cell in cells:
        faces = {a: (cell.expert_action(a) if rng.random() < 0.7 else int(rng.integers(4)))
                 for a in cell.arm_names}
        for arm, out in cell.push(faces).items():
            if out.violation:
                cell.hard_reset(arm)


def _observe_all(cells: list[TwinCell]) -> None:
    """What a twin host reports per timestep: images, ground truth, the expert's choice."""
    for cell in cells:
        cell.observe()
        for a in cell.arm_names:
            cell.arm_state(a)
            cell.expert_action(a)


def _timestep(cells: list[TwinCell], rng: np.random.Generator) -> None:
    _push_all(cells, rng)
    _observe_all(cells)


def _worker(conn: Connection, seeds: list[int]) -> None:
    cells = [TwinCell(s) for s in seeds]
    rng = np.random.default_rng(seeds[0])
    while conn.recv() == "step":
        _timestep(cells, rng)
        conn.send("done")
    for c in cells:
        c.close()


def bench_serial(n_cells: int, steps: int) -> tuple[float, float, float, float, float]:
    """Median timestep, its push and observe parts, its CPU time, and the build time (ms).

    The CPU time (this process's, ``time.process_time``) is the figure to compare across
    runs on a shared machine: wall time also counts the other processes' turns."""
    start = time.perf_counter()
    cells = [TwinCell(seed) for seed in range(n_cells)]
    build = time.perf_counter() - start
    rng = np.random.default_rng(0)
    _timestep(cells, rng)  # warm-up
    total, push, observe, cpu = [], [], [], []
    for _ in range(steps):
        c0 = time.process_time()
        t0 = time.perf_counter()
        _push_all(cells, rng)
        t1 = time.perf_counter()
        _observe_all(cells)
        t2 = time.perf_counter()
        cpu.append(time.process_time() - c0)
        total.append(t2 - t0)
        push.append(t1 - t0)
        observe.append(t2 - t1)
    for c in cells:
        c.close()
    med = statistics.median
    return (med(total) * 1e3, med(push) * 1e3, med(observe) * 1e3, med(cpu) * 1e3,
            build * 1e3)


def bench_processes(n_cells: int, steps: int, n_proc: int) -> float:
    ctx = mp.get_context("spawn")
    pipes, procs = [], []
    for k in range(n_proc):
        parent, child = ctx.Pipe()
        p = ctx.Process(target=_worker, args=(child, list(range(k, n_cells, n_proc))))
        p.start()
        pipes.append(parent)
        procs.append(p)
    try:
        times = []
        for i in range(steps + 1):
            t0 = time.perf_counter()
            for c in pipes:
                c.send("step")
            for c in pipes:
                c.recv()
            if i:  # the first is the warm-up
                times.append(time.perf_counter() - t0)
    finally:
        for c in pipes:
            c.send("stop")
        for p in procs:
            p.join(timeout=10)
    return statistics.median(times) * 1e3


def bench_images(n: int) -> tuple[float, float, float]:
    """Pictures/s: the cell's observe (fresh render) vs the bare render, same run."""
    cell = TwinCell(0)
    cam = cell.camera
    view, proj = cell.camera_matrices
    client = cell.physics_client
    t0 = time.perf_counter()
    for _ in range(n):
        cell.refresh()
        cell.observe()
    ours = n / (time.perf_counter() - t0)
    t0 = time.perf_counter()
    for _ in range(n):
        pb.getCameraImage(cam.width, cam.height, view, proj, renderer=pb.ER_TINY_RENDERER,
                          physicsClientId=client)
    bare = n / (time.perf_counter() - t0)
    cell.close()
    # Reference: the same camera with a table mesh filling the view.
    c = pb.connect(pb.DIRECT)
    vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[1.0, 0.5, 0.01],
                               rgbaColor=[0.6, 0.6, 0.58, 1.0], physicsClientId=c)
    pb.createMultiBody(0.0, -1, vis, basePosition=[0.0, 0.0, -0.01], physicsClientId=c)
    m = max(n // 5, 20)
    t0 = time.perf_counter()
    for _ in range(m):
        pb.getCameraImage(cam.width, cam.height, view, proj, renderer=pb.ER_TINY_RENDERER,
                          physicsClientId=c)
    table = m / (time.perf_counter() - t0)
    pb.disconnect(physicsClientId=c)
    return ours, bare, table


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=int, default=50)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3, help="best of this many runs")
    parser.add_argument("--processes", type=int, default=2)
    parser.add_argument("--images", type=int, default=1000)
    args = parser.parse_args(argv)

    ser, push, observe, cpu, build = min(bench_serial(args.cells, args.steps)
                                         for _ in range(args.repeats))
    par = min(bench_processes(args.cells, args.steps, args.processes)
              for _ in range(args.repeats))
    ours, bare, table = max((bench_images(args.images) for _ in range(args.repeats)),
                            key=lambda r: r[0])
    arms = 2 * args.cells
    print(f"twin fleet: {args.cells} cells = {arms} arms, median of {args.steps} timesteps, "
          f"best of {args.repeats}")
    print(f"  build {args.cells} cells: {build:.0f} ms")
    print(f"  timestep, 1 process:   {ser:7.1f} ms  ratio to the {TARGET_MS:.0f} ms target "
          f"{ser / TARGET_MS:.2f}  ({ser / arms:.2f} ms per arm)")
    print(f"    of which pushes (physics) {push:.1f} ms, observe (render, crops, "
          f"ground truth, expert) {observe:.1f} ms; CPU time {cpu:.1f} ms "
          f"(wall / CPU {ser / cpu:.2f}: above 1 = other processes' turns)")
    print(f"  timestep, {args.processes} processes: {par:7.1f} ms  ratio to the target "
          f"{par / TARGET_MS:.2f}  speed-up {ser / par:.2f}x")
    print("images, one cell (2 arms per picture):")
    print(f"  observe (render + crops + goals): {ours:7.0f} pictures/s "
          f"({2 * ours:.0f} arm images/s)")
    print(f"  bare getCameraImage, same camera: {bare:7.0f} pictures/s  ratio {ours / bare:.2f}")
    print(f"  reference, a table mesh in view:  {table:7.0f} pictures/s  "
          f"(observe is {ours / table:.1f}x that)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
