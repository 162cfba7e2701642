"""How much does one allocation cost, next to sorting the keys it has to sort anyway?

Why this exists: the allocator runs once per timestep for the whole fleet, inside the
loop's critical path. Sorting the N keys (np.lexsort) is the unavoidable core; this
benchmark reports Allocator.step's time per step and its ratio to that lexsort alone,
on the same keys in the same run, for a paper-scale-and-beyond fleet (N=1000 arms,
M=100 humans, K=3: C.U.R.'s (c, u, r)).

    .venv/bin/python benchmarks/bench_allocator.py [--steps 2000] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from testbed.fleet.allocator import Allocator

N, M, K = 1000, 100, 3
T_TELEOP, T_RESET = 5, 5  # the paper's simulation values (appendix 8.3)


def make_inputs(steps: int, seed: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """C.U.R.-like keys: a few violating arms (c = 1), thresholded u and r, many zeros."""
    rng = np.random.default_rng(seed)
    keys, violating = [], []
    viol = np.zeros(N, dtype=bool)
    for _ in range(steps):
        viol = (viol & (rng.random(N) > 0.2)) | (rng.random(N) < 0.01)
        u = rng.random(N) * 0.2
        r = rng.random(N)
        key = np.stack([viol.astype(float), np.where(u >= 0.05, u, 0.0),
                        np.where(r >= 0.5, r, 0.0)], axis=1)
        keys.append(key)
        violating.append(viol.copy())
    return keys, violating


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=5, help="best of this many runs")
    args = parser.parse_args(argv)
    keys, violating = make_inputs(args.steps, args.seed)

    best_step = best_sort = float("inf")
    for _ in range(args.repeats):
        alloc = Allocator(N, M, T_TELEOP, T_RESET, seed=args.seed)
        start = time.perf_counter()
        for key, viol in zip(keys, violating, strict=True):
            alloc.step(key, viol)
        best_step = min(best_step, time.perf_counter() - start)

        start = time.perf_counter()
        for key in keys:
            np.lexsort(-key[:, ::-1].T)
        best_sort = min(best_sort, time.perf_counter() - start)

    us_step = best_step / args.steps * 1e6
    us_sort = best_sort / args.steps * 1e6
    busy = int((alloc.assignment >= 0).sum())
    print(f"Allocator.step  N={N} M={M} K={K}: {us_step:8.1f} us/step "
          f"(best of {args.repeats} x {args.steps} steps; {busy} arms assisted at the end)")
    print(f"np.lexsort(keys) alone:          {us_sort:8.1f} us/step")
    print(f"ratio step / lexsort:            {us_step / us_sort:8.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
