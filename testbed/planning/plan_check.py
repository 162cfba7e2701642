"""``testbed plan ... --against RUNS...``: the plan's predictions beside what a later sweep
measured, point by point.

Why: a plan is a model, and a lab that runs some of the points it planned (a short sweep
on the twin, or the first days on the robots) should see, in the plan's own terms,
whether the model held: per point and metric, the mean of the measured runs against the
predicted interval, and per metric how many points fell inside. The measured runs are
read exactly as the fit reads its own (:func:`testbed.planning.plan_fit.fit_runs`:
each run's N from its rows, M from its config, its metrics by ``run_metrics``), matched
to the plan by label (algorithm or protocol way), and grouped by (N, M).

The predicted interval is of the mean of ``--runs`` simulated runs: compare a point with
that many measured runs (a sweep's seeds per point); a point measured with another
number of runs is still compared, with a note. A point outside the grid, or runs of
another length than the plan's ``--steps``, are left out with a note saying what to pass.
"""

from __future__ import annotations

import csv
import io
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from testbed.core.atomic import atomic_write_bytes
from testbed.core.config import ConfigError
from testbed.planning.plan import (
    TITLES,
    AlgorithmPlan,
    Plan,
    PlanOptions,
    find_runs,
    fmt_metric,
    interval,
)
from testbed.planning.plan_fit import METRICS, fit_runs

__all__ = ["PointCheck", "check_csv", "check_markdown", "check_plans", "write_checks"]


@dataclass(frozen=True)
class PointCheck:
    """One metric at one point: the measured runs' mean against the predicted interval."""

    label: str
    n: int
    m: int
    runs: int
    metric: str
    measured: float
    mean: float
    low: float
    high: float

    @property
    def inside(self) -> bool:
        return self.low <= self.measured <= self.high


def check_plans(plans: list[AlgorithmPlan], dirs: list[Path], options: PlanOptions
                ) -> tuple[list[PointCheck], list[str]]:
    """Every measured point of ``dirs`` that a plan predicts, and a note per thing left
    out or to keep in mind."""
    found = find_runs(dirs)
    if not found:
        raise ConfigError("--against: no run found (no steps.jsonl in or below the folders "
                          "given)")
    fits, notes = fit_runs(found, options.bin_steps)
    by_label = {p.fit.label: p for p in plans}
    checks: list[PointCheck] = []
    for fit in fits:
        plan = by_label.get(fit.label)
        if plan is None:
            notes.append(f"--against: {len(fit.runs)} run(s) of {fit.label} left out: the "
                         f"plan has no fit of {fit.label} (it has {', '.join(by_label)})")
            continue
        groups: dict[tuple[int, int], list[dict[str, float]]] = defaultdict(list)
        lengths: dict[tuple[int, int], set[int]] = defaultdict(set)
        for path, point, measured in zip(fit.runs, fit.points, fit.measured, strict=True):
            groups[point].append(measured)
            lengths[point].add(_steps(path))
        for point in sorted(groups):
            n, m = point
            if lengths[point] != {plan.steps}:
                notes.append(f"--against: {fit.label} N={n}, M={m} left out: its runs have "
                             f"{'/'.join(map(str, sorted(lengths[point])))} steps, the plan "
                             f"{plan.steps} (give --steps to match)")
                continue
            if point not in plan.points:
                notes.append(f"--against: {fit.label} N={n}, M={m} left out: not in the "
                             "plan's grid (add it to --robots and --humans)")
                continue
            runs = groups[point]
            if len(runs) != options.runs:
                notes.append(f"--against: {fit.label} N={n}, M={m} has {len(runs)} run(s); "
                             f"the intervals are of the mean of {options.runs} (--runs)")
            for metric in METRICS:
                mean, low, high = interval(plan.points[point][metric])
                measured = float(np.mean([r[metric] for r in runs]))
                checks.append(PointCheck(fit.label, n, m, len(runs), metric, measured,
                                         mean, low, high))
    return checks, notes


def _steps(run: Path) -> int:
    with (run / "steps.jsonl").open() as f:
        return sum(1 for line in f if line.strip())


def check_markdown(checks: list[PointCheck], notes: list[str]) -> str:
    """Per label: a row per point (measured, predicted interval, and whether it is
    inside, per metric), then per metric how many points were inside."""
    lines: list[str] = []
    for label in dict.fromkeys(c.label for c in checks):
        mine = [c for c in checks if c.label == label]
        points = list(dict.fromkeys((c.n, c.m) for c in mine))
        cols = ["N", "M", "runs", *(TITLES[k] for k in METRICS)]
        lines += [f"## Predicted and measured: {label}", "",
                  "Each cell: the measured runs' mean, then the predicted interval; "
                  "`in` when the mean is inside it, `OUT` when not.", "",
                  "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
        for n, m in points:
            cells = {c.metric: c for c in mine if (c.n, c.m) == (n, m)}
            runs = next(iter(cells.values())).runs
            lines.append(f"| {n} | {m} | {runs} | " + " | ".join(
                _cell(cells[k]) for k in METRICS) + " |")
        lines += ["", "Inside the interval, of " + f"{len(points)} point(s): " + ", ".join(
            f"{TITLES[k]} {sum(c.inside for c in mine if c.metric == k)}" for k in METRICS)
            + ".", ""]
    lines += [f"{n}." for n in notes]
    return "\n".join(lines) + ("\n" if lines else "")


def _cell(c: PointCheck) -> str:
    return (f"{fmt_metric(c.metric, c.measured)} [{fmt_metric(c.metric, c.low)}, "
            f"{fmt_metric(c.metric, c.high)}] " + ("in" if c.inside else "**OUT**"))


def check_csv(checks: list[PointCheck]) -> str:
    """``plan-check.csv``: one row per label, point and metric."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["algorithm", "N", "M", "runs", "metric", "measured", "mean", "low", "high",
                "inside"])
    for c in checks:
        w.writerow([c.label, c.n, c.m, c.runs, c.metric, f"{c.measured:.6g}",
                    f"{c.mean:.6g}", f"{c.low:.6g}", f"{c.high:.6g}", int(c.inside)])
    return buf.getvalue()


def write_checks(plan: Plan, against: list[Path], options: PlanOptions) -> Plan:
    """``against`` (measured runs) beside ``plan``'s predictions: appended to its plan.md
    and written to plan-check.csv in its folder."""
    checks, check_notes = check_plans(plan.plans, against, options)
    plan.markdown += "\n" + check_markdown(checks, check_notes)
    atomic_write_bytes(plan.files[0], plan.markdown.encode())
    plan.files.insert(2, plan.folder / "plan-check.csv")
    atomic_write_bytes(plan.files[2], check_csv(checks).encode())
    return plan
