"""How long does ``testbed plan`` take for the 3 x 3 grid, next to its 10 s budget?

Why this exists: the planner is meant to answer "how many people for how many arms" in
seconds, where a measured sweep of the same grid takes the twin tens of minutes and the
robots days (issue 31: the whole 3 x 3 grid, N in {4, 8, 16} x M in {1, 2, 4}, 250 steps,
intervals included, under 10 s on this machine). This benchmark plans that grid end to
end (posterior draws, 200 replicates per point, the grid plus the runs' own point and its
two neighbours and the check, plan.md, plan.csv and the figure) and prints its time and
its ratio to 10 s. Beside it, two references measured in the same run:

* the same simulation with the real ``Allocator`` stepped once per replicate (engine
  ``real``) on one point, scaled to the grid: what vectorising over replicates saves;
* with ``--runs DIR`` (finished runs or a protocol), the plan fitted from them, and the
  wall time of one of their runs (its rows' ``wall_time``): a plan against a trial.

Without ``--runs`` the fit is made up from the twin's own figures (a C.U.R. protocol of
2 scripted humans at N = 4: docs/notes/plan.md), so a fresh clone can run it.

    .venv/bin/python benchmarks/bench_plan.py [--runs runs/protocol-twin-learning]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from testbed.planning.plan import PlanOptions, find_runs, write_fits
from testbed.planning.plan_fit import (
    HumanFit,
    Outcomes,
    PlanFit,
    Rates,
    fit_runs,
)
from testbed.planning.plan_sim import FleetShape, sim_params, simulate
from testbed.planning.plan_trouble import TroubleCounts
from testbed.records.steps import read_steps

BUDGET_S = 10.0
GRID = PlanOptions(robots=(4, 8, 16), humans=(1, 2, 4), steps=250, replicates=200)


def twin_like_fit() -> PlanFit:
    """A fit with the twin's figures (C.U.R., 6 trials x 120 steps, N = 4, M = 2):
    requests ~0.3 per arm-step, the policy 0.17 success and 0.012 violation per push,
    "ana" instant and "bo" 2 steps late."""
    fit = PlanFit(label="cur", algorithm="cur", runs=[Path("twin-like")], points=[(4, 2)],
                  steps=120, t_T=3, t_R=5, t_I=0, bin_steps=25, order="resets_first",
                  initial_period=False)
    fit.requests = Rates(k=[200, 190, 170, 160, 120], n=[660, 640, 650, 620, 500])
    fit.continues = Rates(k=[30, 25, 28, 24, 20], n=[90, 90, 85, 85, 80])
    fit.eligible = Rates(k=[30] * 5, n=[30] * 5)
    fit.policy = Outcomes(counts=[[56, 3, 275], [66, 4, 270], [63, 4, 300], [59, 5, 289],
                                  [52, 7, 217]])
    ana, bo = HumanFit(0, "ana"), HumanFit(1, "bo", latency=[2] * 40,
                                            reset_steps=[7] * 6, present=720)
    ana.pushes = Outcomes(counts=[[187, 0, 349]])
    ana.latency, ana.reset_steps, ana.present = [0] * 120, [5] * 20, 720
    bo.pushes = Outcomes(counts=[[52, 4, 144]])
    fit.humans = [ana, bo]
    fit.trouble = TroubleCounts(  # the twin fit's figures (docs/notes/plan.md)
        calm_ask=np.array([[150, 650], [140, 620], [110, 640], [100, 610], [70, 500.0]]),
        trouble_ask=np.array([270, 290.0]), to_trouble=np.array([170, 2000.0]),
        recover=np.array([30, 280.0]), fixed=np.array([400, 480.0]),
        start=np.array([5, 60.0]), calm_push=fit.policy.array(5),
        trouble_push=np.array([4, 25, 85.0]))
    fit.measured = [dict.fromkeys(("successes", "hard_resets", "idle_time", "human_actions",
                                   "rohe", "utilisation", "wait", "unserved"), 0.0)]
    return fit


def run_seconds(path: Path) -> float:
    """One run's wall time from its rows (first step's start to last step's end)."""
    rows = read_steps(path / "steps.jsonl")
    return float(rows[-1]["wall_time"] - rows[0]["wall_time"] + rows[0]["duration_s"])


def real_engine_seconds(fit: PlanFit, replicates: int) -> float:
    """The grid's simulation time with the real Allocator per replicate, from one point
    (N = 8, M = 2) scaled by the grid's arm-steps."""
    draws = fit.draw(replicates, np.random.default_rng(0))
    shape = FleetShape(fit.t_T, fit.t_R, fit.t_I, fit.bin_steps, fit.order,
                       fit.initial_period)
    start = time.perf_counter()
    simulate(sim_params(draws, 2), shape, 8, 2, GRID.steps or 250, seed=0, engine="real")
    one = time.perf_counter() - start
    points = len(GRID.robots) * len(GRID.humans) + 3  # the grid, own point, 2 neighbours
    return one * points


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, help="fit from these runs (default: made up)")
    parser.add_argument("--repeats", type=int, default=3, help="best of this many")
    args = parser.parse_args(argv)
    fit_s = 0.0
    if args.runs is not None:
        start = time.perf_counter()
        fits, notes = fit_runs(find_runs([args.runs]), GRID.bin_steps)
        fit_s = time.perf_counter() - start
        fits = fits[:1]
        trial_s = run_seconds(fits[0].runs[0])
    else:
        fits, notes, trial_s = [twin_like_fit()], [], float("nan")
    times = []
    with tempfile.TemporaryDirectory() as out:
        for _ in range(args.repeats):
            start = time.perf_counter()
            write_fits(fits, notes, GRID, Path(out))
            times.append(time.perf_counter() - start)
    best = min(times)
    real = real_engine_seconds(fits[0], GRID.replicates)
    print(f"plan of {fits[0].label}: 3 x 3 grid (N 4,8,16 x M 1,2,4), {GRID.steps} steps, "
          f"{GRID.replicates} replicates, files included: {best:.2f} s (best of "
          f"{args.repeats}; the first, matplotlib's import included: {times[0]:.2f} s)")
    if args.runs is not None:
        print(f"  + the fit from {len(find_runs([args.runs]))} run folder(s): {fit_s:.2f} s")
    total = best + fit_s
    print(f"  ratio to the {BUDGET_S:.0f} s budget: {total / BUDGET_S:.2f}")
    print(f"  the same simulation with the real Allocator per replicate: ~{real:.1f} s "
          f"(batch is {real / best:.1f}x faster, files included)")
    if trial_s == trial_s:
        print(f"  one run of the fit ({fits[0].runs[0].name}, {fits[0].steps} steps) took "
              f"{trial_s:.0f} s: the plan is {total / trial_s:.3f} of it")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
