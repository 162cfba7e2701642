"""``testbed plan RUNS... --robots 4,8,16 --humans 1,2,4``: how many people for how many arms.

Why: a physical sweep of fleet sizes costs a lab days of robots and people; the runs it
already has say how often its arms ask for help and how long its people take. This
module fits those per algorithm (:mod:`testbed.planning.plan_fit`), replays Algorithm
1 on them for every N x M point (:mod:`testbed.planning.plan_sim`) and writes:

* ``plan.md`` (also printed): per algorithm, the fitted processes, a table of every
  point's predictions with intervals, the check at the runs' own point (predicted
  against measured), where one more human stops paying, and the one-line answer to "one
  more person or two more arms";
* ``plan.csv``: one row per algorithm, point and metric (``algorithm, point, N, M,
  metric, mean, low, high``), for comparing with a measured sweep;
* ``plan-<algorithm>.png``: the paper's figure 7 (successes, idle time, hard resets,
  human actions, ROHE, utilisation against M, one line per N, shaded interval).

Intervals: per replicate the fitted rates are redrawn from their posteriors
(``PlanFit.draw``) and one run (or the mean of ``runs`` runs, as a sweep averages its
seeds) is simulated with them; the interval is the central ``LEVEL`` of the
replicates. The same draw serves every point of a replicate, so differences between
points (the marginal human, person against arms) are paired.

"Stops paying" (per N, along the grid's M): going from M to the next M' stops paying
when the successes it adds per added human fall below ``min_gain`` of the successes at
M (default 5%), or when ROHE falls. Why both: ROHE = (M/N) S/(1+A) grows with M by
itself, so it can rise while the extra person adds almost nothing a lab can use; and a
fall in ROHE means the added successes do not cover the added help even by the paper's
own measure. 5%: below that a person's effect is inside the trial-to-trial spread of
successes (~8% on the twin; docs/notes/plan.md).
"""

from __future__ import annotations

import csv
import io
import itertools
import re
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from testbed.core.atomic import atomic_write_bytes
from testbed.core.config import ConfigError
from testbed.planning.plan_fit import BIN_STEPS, METRICS, Draws, PlanFit, fit_runs
from testbed.planning.plan_sim import FleetShape, sim_params, simulate
from testbed.results.report import find_runs  # the report's rule, re-exported

__all__ = ["LEVEL", "AlgorithmPlan", "Plan", "PlanOptions", "find_runs", "fmt_metric",
           "interval", "plan_algorithm", "planned_on_site", "write_fits", "write_plan"]

LEVEL: Final = 0.95
FloatArray = npt.NDArray[np.float64]
Point = tuple[int, int]
TITLES: Final = {"successes": "successes", "hard_resets": "hard resets",
                 "idle_time": "idle time", "human_actions": "human actions",
                 "rohe": "ROHE", "utilisation": "utilisation", "wait": "wait (steps)",
                 "unserved": "unserved requests"}
FIGURE: Final = ("successes", "idle_time", "hard_resets", "human_actions", "rohe",
                 "utilisation")


@dataclass(frozen=True)
class PlanOptions:
    """What ``testbed plan`` was asked (its flags)."""

    robots: tuple[int, ...]
    humans: tuple[int, ...]
    steps: int | None = None
    """Steps per planned run (default: the fit's longest run)."""
    replicates: int = 200
    runs: int = 1
    """Simulated runs averaged per replicate: a sweep's seeds per point."""
    bin_steps: int = BIN_STEPS
    min_gain: float = 0.05
    seed: int = 0
    on_site: int | None = None
    """How many of each planned M people are on site (the first ones; the rest remote,
    teleop only); None: each planned person in the place of the fitted person they are
    drawn as (:func:`planned_on_site`)."""


@dataclass
class AlgorithmPlan:
    """One algorithm's fit and its predictions, per point: metric -> (R,) values."""

    fit: PlanFit
    steps: int
    points: dict[Point, dict[str, FloatArray]]
    check: dict[str, FloatArray]
    """The runs' own point simulated at the runs' own length (against ``fit.measured``)."""
    knees: list[str] = field(default_factory=list)
    answer: str = ""


@dataclass
class Plan:
    folder: Path
    markdown: str
    plans: list[AlgorithmPlan]
    files: list[Path]
    notes: list[str]


def write_plan(dirs: list[Path], options: PlanOptions, out: Path) -> Plan:
    """Fit, simulate, and write plan.md, plan.csv and one PNG per algorithm in ``out``
    (measured runs beside the predictions: ``plan_check.write_checks``)."""
    found = find_runs(dirs)
    if not found:
        raise ConfigError("RUN_OR_PROTOCOL_DIR: no run found (no steps.jsonl in or below "
                          "the folders given)")
    fits, notes = fit_runs(found, options.bin_steps)
    return write_fits(fits, notes, options, out)


def write_fits(fits: list[PlanFit], notes: list[str], options: PlanOptions,
               out: Path) -> Plan:
    """Plan every fit and write the files (``write_plan`` after the fit; a benchmark's
    made-up fit)."""
    plans = [plan_algorithm(fit, options) for fit in fits]
    out.mkdir(parents=True, exist_ok=True)
    files = [out / "plan.md", out / "plan.csv"]
    md = "\n".join(_markdown(p, options) for p in plans)
    md += "".join(f"\n{n}.\n" for n in notes)
    atomic_write_bytes(files[0], md.encode())
    atomic_write_bytes(files[1], _csv(plans).encode())
    for p in plans:
        png = out / f"plan-{_slug(p.fit.label)}.png"
        atomic_write_bytes(png, _figure(p, options))
        files.append(png)
    return Plan(out, md, plans, files, notes)


def _slug(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", label)


def planned_on_site(fit: PlanFit, num_humans: int, on_site: int | None = None
                    ) -> npt.NDArray[np.bool_]:
    """(M,) which planned people are on site (only they are given hard resets).

    ``on_site`` given: the first ``min(on_site, M)``. Else planned person j is fitted
    person j mod H (``plan_sim.sim_params``) and takes that person's place in the runs;
    were nobody on site then (the runs' first people remote), person 0 is: a fleet
    with people needs one in the room, as its config does (``HumansConfig``)."""
    if on_site is not None:
        return np.arange(num_humans) < on_site
    fitted = [h.on_site for h in fit.humans] or [True]
    place = np.array([fitted[j % len(fitted)] for j in range(num_humans)], dtype=bool)
    if num_humans and not place.any():
        place[0] = True
    return place


def plan_algorithm(fit: PlanFit, options: PlanOptions) -> AlgorithmPlan:
    """Every point of the grid, the runs' own point and its two neighbours (one more
    person, two more arms), all with the same posterior draws."""
    steps = options.steps or fit.steps
    draws = fit.draw(options.replicates, np.random.default_rng([options.seed, 1]))
    draws = _repeat(draws, options.runs)
    shape = FleetShape(fit.t_T, fit.t_R, fit.t_I, fit.bin_steps, fit.order,
                       fit.initial_period)
    n0, m0 = fit.own
    wanted = [(n, m) for n in options.robots for m in options.humans]
    wanted += [p for p in ((n0, m0), (n0, m0 + 1), (n0 + 2, m0)) if p not in wanted]

    def run(point: Point, length: int, salt: int) -> dict[str, FloatArray]:
        n, m = point
        params = sim_params(draws, m, planned_on_site(fit, m, options.on_site))
        values = simulate(params, shape, n, m, length,
                          seed=np.random.SeedSequence([options.seed, n, m, salt]))
        return {k: v.reshape(options.replicates, options.runs).mean(axis=1)
                for k, v in values.items()}

    points = {p: run(p, steps, 0) for p in wanted}
    plan = AlgorithmPlan(fit, steps, points, run((n0, m0), fit.steps, 1))
    plan.knees = [_knee(plan, n, options) for n in options.robots]
    plan.answer = _answer(plan)
    return plan


def _repeat(draws: Draws, k: int) -> Draws:
    """Each replicate's draw ``k`` times in a row (its ``k`` simulated runs)."""
    if k == 1:
        return draws
    keep = {"latency_values", "reset_values", "trouble"}
    trouble = replace(draws.trouble, **{f.name: np.repeat(getattr(draws.trouble, f.name), k,
                                                          axis=0)
                                        for f in fields(draws.trouble)})
    return replace(draws, trouble=trouble,
                   **{f.name: np.repeat(getattr(draws, f.name), k, axis=0)
                      for f in fields(draws) if f.name not in keep})


def interval(v: FloatArray) -> tuple[float, float, float]:
    """The replicates' mean and central ``LEVEL`` interval."""
    lo, hi = np.quantile(v, [(1 - LEVEL) / 2, (1 + LEVEL) / 2])
    return float(v.mean()), float(lo), float(hi)


def fmt_metric(metric: str, x: float) -> str:
    """A metric's value as the plan's tables print it."""
    return (f"{x:.3f}" if metric in ("rohe", "utilisation", "unserved")
            else f"{x:.2f}" if metric == "wait" else f"{x:.1f}")


def _cell(metric: str, v: FloatArray) -> str:
    mean, lo, hi = interval(v)
    return f"{fmt_metric(metric, mean)} [{fmt_metric(metric, lo)}, {fmt_metric(metric, hi)}]"


def _knee(plan: AlgorithmPlan, n: int, options: PlanOptions) -> str:
    """Where one more human stops paying at N = n (module doc), in one line."""
    ms = sorted(options.humans)
    for m, nxt in itertools.pairwise(ms):
        a, b = plan.points[(n, m)], plan.points[(n, nxt)]
        base = np.maximum(a["successes"], 1.0)
        gain = (b["successes"] - a["successes"]) / (nxt - m) / base
        d_rohe = b["rohe"] - a["rohe"]
        g, glo, ghi = interval(gain)
        if g < options.min_gain or d_rohe.mean() < 0:
            why = (f"ROHE falls {interval(a['rohe'])[0]:.3f} -> {interval(b['rohe'])[0]:.3f}"
                   if d_rohe.mean() < 0 else f"below {options.min_gain:.0%}")
            return (f"N={n}: one more human stops paying after M={m} (M={m}->{nxt}: "
                    f"{g:+.1%} successes per added human [{glo:+.1%}, {ghi:+.1%}]; {why})")
    if len(ms) < 2:
        return f"N={n}: one value of M only; nothing to compare"
    return (f"N={n}: every added human still pays up to M={ms[-1]}, the grid's largest "
            f"(at least {options.min_gain:.0%} more successes each, ROHE not falling)")


def _answer(plan: AlgorithmPlan) -> str:
    """"One more person or two more arms", decided by successes (paired by replicate)."""
    n, m = plan.fit.own
    here, person, arms = (plan.points[(n, m)], plan.points[(n, m + 1)],
                          plan.points[(n + 2, m)])
    dp = person["successes"] - here["successes"]
    da = arms["successes"] - here["successes"]
    diff, lo, hi = interval(da - dp)
    choice = ("two more arms" if lo > 0 else "one more person" if hi < 0
              else "either (the difference is inside the interval)")
    r0, rp, ra = (interval(x["rohe"])[0] for x in (here, person, arms))
    return (f"{plan.fit.label} at N={n}, M={m}: {choice}: one more person "
            f"{_cell('successes', dp)} successes (ROHE {r0:.3f} -> {rp:.3f}), two more "
            f"arms {_cell('successes', da)} (ROHE {r0:.3f} -> {ra:.3f}); arms minus "
            f"person {diff:+.1f} [{lo:+.1f}, {hi:+.1f}]")


def _markdown(plan: AlgorithmPlan, options: PlanOptions) -> str:
    fit = plan.fit
    n0, m0 = fit.own
    head = (f"## Plan: {fit.label}\n\nFit: {len(fit.runs)} run(s) of {fit.algorithm} "
            f"({', '.join(p.name for p in fit.runs)}) at N={n0}, M={m0}, up to {fit.steps} "
            f"steps (t_T={fit.t_T}, t_R={fit.t_R}); predicted for {plan.steps} steps, "
            f"{options.replicates} replicates"
            + (f" of the mean of {options.runs} runs" if options.runs > 1 else "")
            + f", {LEVEL:.0%} intervals.\n" + _places(fit, options))
    cols = ["N", "M", *(TITLES[m] for m in METRICS)]
    lines = [head, "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    grid = [(n, m) for n in options.robots for m in options.humans]
    for p in grid:
        lines.append(f"| {p[0]} | {p[1]} | "
                     + " | ".join(_cell(k, plan.points[p][k]) for k in METRICS) + " |")
    lines += ["", *_check(plan), "", *_processes(fit), "", "Where one more human stops "
              f"paying (successes per added human below {options.min_gain:.0%} of those "
              "at M, or ROHE falling):", "", *(f"- {k}" for k in plan.knees), "",
              f"One more person or two more arms? {plan.answer}.", *fit.notes, ""]
    return "\n".join(lines)


def _places(fit: PlanFit, options: PlanOptions) -> str:
    """Who is on site, in a line, when anyone is remote (else nothing: every plan
    before the places existed reads as it did)."""
    if options.on_site is not None:
        return (f"\nPlaces: the first {options.on_site} of each M on site (teleop and hard "
                "resets), the rest remote (teleop only).\n")
    if all(h.on_site for h in fit.humans):
        return ""
    who = ", ".join(f"{h.name} {'on site' if h.on_site else 'remote'}" for h in fit.humans)
    return (f"\nPlaces as in the runs ({who}): planned person j is fitted person j mod "
            f"{len(fit.humans)}, in their place; only those on site reset.\n")


def _check(plan: AlgorithmPlan) -> list[str]:
    """The runs' own point: what they measured against what the plan predicts for it."""
    fit = plan.fit
    measured = {k: np.array([m[k] for m in fit.measured]) for k in METRICS}
    cols = ["", *(TITLES[m] for m in METRICS)]
    return [f"Check at the runs' own point (N={fit.own[0]}, M={fit.own[1]}, "
            f"{fit.steps} steps):", "", "| " + " | ".join(cols) + " |",
            "|" + "---|" * len(cols),
            "| measured (mean of runs) | " + " | ".join(
                fmt_metric(k, float(measured[k].mean())) for k in METRICS) + " |",
            "| predicted | " + " | ".join(_cell(k, plan.check[k]) for k in METRICS) + " |"]


def _processes(fit: PlanFit) -> list[str]:
    """What the fit found, in two small tables and a line: by phase (the requests seen,
    and the calm arm of the trouble model), the trouble state, and by human."""
    b = fit.bins
    req = fit.requests.means(b)
    c = fit.trouble
    assert c is not None
    calm_ask = (c.calm_ask[:, 0] + 1) / (c.calm_ask[:, 1] + 2)
    pushes = c.calm_push.sum(-1)
    lines = ["Fitted, by phase (requests: what the rows show of arms neither violating nor "
             "held; the rest: the calm arm of the trouble model, expected counts):", "",
             "| steps | requests per arm-step | a calm arm asks | calm pushes | "
             "success per push | violation per push |", "|---|---|---|---|---|---|"]
    for i in range(b):
        rate = c.calm_push[i] / pushes[i] if pushes[i] else np.full(3, np.nan)
        lines.append(f"| {i * fit.bin_steps}-{(i + 1) * fit.bin_steps - 1} | {req[i]:.3f} | "
                     f"{calm_ask[i]:.3f} | {pushes[i]:.0f} | {rate[0]:.3f} | {rate[1]:.3f} |")
    tp = c.trouble_push / max(c.trouble_push.sum(), 1.0)

    def r(kn: FloatArray) -> str:
        return f"{(kn[0] + 1) / (kn[1] + 2):.3f}"

    lines += ["", f"In trouble (the arm's hidden state, {c.trouble_ask[1]:.0f} of "
              f"{c.trouble_ask[1] + c.calm_ask[:, 1].sum():.0f} arm-steps): it asks "
              f"{r(c.trouble_ask)} a step, its policy pushes succeed {tp[0]:.3f} and violate "
              f"{tp[1]:.3f}; a calm arm on its own falls into trouble {r(c.to_trouble)} a "
              f"step, a troubled one recovers alone {r(c.recover)}; after a human's push "
              f"it is calm {r(c.fixed)}; after a violation (and at the start) troubled "
              f"{r(c.start)}."]
    lines += ["", "| human | pushes | success per push | violation per push | latency "
              "(steps) | reset (steps) | available |", "|---|---|---|---|---|---|---|"]
    for h in fit.humans:
        tot = h.pushes.total()
        n = tot.sum()
        lat = f"{np.mean(h.latency):.2f}" if h.latency else "-"
        rst = f"{np.mean(h.reset_steps):.2f}" if h.reset_steps else "-"
        avail = h.present / (h.present + h.away) if h.present + h.away else 1.0
        lines.append(f"| {h.name} | {int(n)} | "
                     + (f"{tot[0] / n:.3f} | {tot[1] / n:.3f}" if n else "- | -")
                     + f" | {lat} | {rst} | {avail:.3f} |")
    return lines


def _csv(plans: list[AlgorithmPlan]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["algorithm", "point", "N", "M", "metric", "mean", "low", "high"])
    for p in plans:
        for (n, m), values in p.points.items():
            for k in METRICS:
                mean, lo, hi = interval(values[k])
                w.writerow([p.fit.label, f"N{n}-M{m}", n, m, k, round(mean, 6),
                            round(lo, 6), round(hi, 6)])
    return buf.getvalue()


def _figure(plan: AlgorithmPlan, options: PlanOptions) -> bytes:
    """The paper's figure 7 for the plan: each metric against M, one line per N."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ms = sorted(options.humans)
    fig, axes = plt.subplots(2, 3, figsize=(12.6, 7.2))
    for ax, metric in zip(axes.flat, FIGURE, strict=True):
        for n in options.robots:
            stats = np.array([interval(plan.points[(n, m)][metric]) for m in ms])
            ax.plot(ms, stats[:, 0], marker="o", label=f"N = {n}")
            ax.fill_between(ms, stats[:, 1], stats[:, 2], alpha=0.2)
        ax.set_title(TITLES[metric])
        ax.set_xlabel("humans M")
        ax.set_xticks(ms)
        ax.grid(alpha=0.3)
    axes.flat[0].legend()
    fig.suptitle(f"Plan: {plan.fit.label} ({plan.steps} steps, {LEVEL:.0%} intervals)")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()
