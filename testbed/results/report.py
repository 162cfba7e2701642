"""``testbed report``: the table and the curves of the paper's figures, from records only.

Every figure is recomputed from ``steps.jsonl`` (never from a summary someone may have
edited), grouped by algorithm, and written as ``report.md``, ``report.csv`` and one PNG
of the five cumulative curves (successes, hard resets, idle time, human actions, ROHE)
with one line per algorithm, mean +- std over trials as in the paper's figures 6-9.
Only finished runs count: a run whose run.json says ``stopped`` (Esc) or ``running``
(in progress, or killed) is left out, and the report says so in one line.

After the table, ROHE with its parts (``rohe_section``): successes split by who pushed,
human actions, the policy's successes and violations per push, and a paragraph for
each algorithm that is not below C.U.R. by ROHE (the paper's ordering broken) naming
the part that decides it.

Evaluations (``testbed evaluate``: rows ``eval:<algorithm>``) are the paper's Table 2, not
its learning curves: they get a second table (successes, hard resets, idle time; no
human effort to weigh, humans only reset) in report.md and ``report-eval.csv``, and stay
out of the learning table, its CSV and the curves.

What a reviewer needs beyond mean +- std (:mod:`testbed.results.report_tables`): a
95% interval per metric and algorithm, each algorithm against a reference (C.U.R., or
``--reference``) paired by trial with an exact sign-flip p-value, the same for the
evaluations and, per point, for a sweep (its reference: the grid's first point); the
humans by name (``report_humans``); a line for any two algorithms or points whose
records are identical; per run, its frames per class and its episodes per outcome
(``report_classes``: what learning by class has to learn from); for a protocol run
with ``until``, what its sequential test settled and when (``report_sequential``, from
its ``sequential.json``). ``report.html``
(``report_html``) is all of it on one self-contained page, with the metadata that
decides the numbers.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from testbed.core.atomic import atomic_write_bytes
from testbed.records.metrics import cumulative, summarize
from testbed.records.run_dir import EVAL_PREFIX, display_names, evaluation_label
from testbed.records.steps import read_steps
from testbed.results.report_classes import class_counts, classes_table
from testbed.results.report_gain import gain_tables
from testbed.results.report_humans import (
    RunHumans,
    count_humans,
    estimate_humans,
    scripted_profiles,
)
from testbed.results.report_sequential import place_sequential
from testbed.results.report_tables import (
    Table,
    humans_table,
    identical_groups,
    interval_table,
    paired_table,
    steps_digest,
)
from testbed.results.run_record import RunRecord

METRICS = ("successes", "hard_resets", "idle_time", "human_actions", "rohe")
EVAL_METRICS = ("successes", "hard_resets", "idle_time")
TITLES = {
    "successes": "Cumulative successes",
    "hard_resets": "Cumulative hard resets",
    "idle_time": "Cumulative idle time",
    "human_actions": "Cumulative human actions",
    "rohe": "ROHE",
}


def trial_label(key: Any) -> str:
    kind, number = key
    return f"t{number}" if kind == "trial" else f"seed {number}"


@dataclass
class Report:
    folder: Path
    markdown: str
    runs: list[RunRecord]
    notes: list[str] = field(default_factory=list)
    """One line each: what the table leaves out (unfinished runs)."""
    tables: list[Table] = field(default_factory=list)
    """Every table, in the report's order (``Table.key`` names each)."""


def unfinished(path: Path) -> str | None:
    """Why the run in ``path`` is not finished (``None``: it is, or it predates statuses)."""
    meta_path = path / "run.json"
    if not meta_path.exists():
        return None
    meta = json.loads(meta_path.read_text())
    status = meta.get("status")
    if status is None or status == "complete":
        return None
    if status == "stopped":
        return f"stopped at step {meta.get('stopped_at')}"
    return str(status)


def find_runs(dirs: list[Path]) -> list[Path]:
    """Run folders (those with a steps.jsonl) among or below the given folders."""
    found: list[Path] = []
    for d in dirs:
        if (d / "steps.jsonl").exists():
            found.append(d)
        else:
            found.extend(sorted(p.parent for p in d.glob("*/steps.jsonl")))
    return found


def load_run(path: Path) -> RunRecord:
    meta = json.loads((path / "run.json").read_text()) if (path / "run.json").exists() else {}
    opts = meta.get("options", {})
    # an evaluation's label (eval:<algorithm>) keeps it out of the training rows; runs
    # from before labels: an evaluation is marked by its options' "evaluate"
    algorithm = (opts.get("label") or (evaluation_label(None) if opts.get("evaluate") else None)
                 or opts.get("algorithm") or path.name.split("-t")[0])
    config = _config(path)
    num_humans = humans_of(config)
    names = display_names(path, config.get("humans", {}), num_humans)
    steps = read_steps(path / "steps.jsonl")
    summary = summarize(steps, algorithm=algorithm, num_humans=num_humans)
    curves = cumulative(steps, num_humans=num_humans)
    point = meta.get("sweep", {}).get("point", "")
    return RunRecord(path, algorithm, num_humans, summary, curves, rohe_parts(steps),
                     group=point, meta=meta, config=config, humans=names,
                     human_counts=count_humans(steps, num_humans),
                     human_estimates=estimate_humans(steps, num_humans,
                                                     config.get("algorithm", {})),
                     human_profiles=scripted_profiles(config.get("humans", {}), num_humans,
                                                      config.get("algorithm", {})),
                     digest=steps_digest(steps), classes=class_counts(path))


def humans_of(config: dict[str, Any]) -> int:
    """A run's number of humans from its config.toml (2 when it names none, the
    default of runs written before humans were configurable)."""
    return int(config.get("humans", {}).get("count", 2))


def run_summary(path: Path) -> dict[str, Any]:
    """A finished run's metrics (``summarize``) as the report computes them, without
    the rest of its record: what the sequential test reads after each trial."""
    return summarize(read_steps(path / "steps.jsonl"), algorithm="",
                     num_humans=humans_of(_config(path)))


def rohe_parts(steps: list[dict[str, Any]]) -> dict[str, int]:
    """ROHE's numerator split by who pushed: the policy's pushes (autonomous), the
    humans' (teleop), the successes and violations of each."""
    out = dict.fromkeys(("policy_pushes", "policy_successes", "policy_violations",
                         "human_pushes", "human_successes", "human_violations"), 0)
    for step in steps:
        for r in step["robots"]:
            who = {"autonomous": "policy", "teleop": "human"}.get(r["mode"])
            if who is None or r["action"] is None:
                continue
            out[f"{who}_pushes"] += 1
            out[f"{who}_successes"] += bool(r["success"])
            out[f"{who}_violations"] += bool(r["violation"])
    return out


PAPER_FIRST = "cur"
"""The seed reports C.U.R. first by ROHE against every baseline (its Table 1)."""


def _mean(rs: list[RunRecord], get: Any) -> float:
    return float(np.mean([get(r) for r in rs]))


def _rate(rs: list[RunRecord], num: str, den: str) -> float:
    d = sum(r.parts[den] for r in rs)
    return sum(r.parts[num] for r in rs) / d if d else 0.0


def rohe_table(runs: list[RunRecord]) -> Table:
    """Per algorithm, ROHE and its parts (successes by who pushed, human
    actions, the policy's successes and violations per push); then, for each
    algorithm whose ROHE is not below C.U.R.'s (the paper's ordering broken), one
    paragraph that says which part decides it, from these measurements: ROHE's ratio
    is (successes ratio) x ((1 + C.U.R.'s human actions) / (1 + its own)), and the
    larger factor decides."""
    groups = _groups(runs)
    header = ["algorithm", "ROHE", "successes (policy + humans)", "human actions",
              "policy successes / push", "policy violations / push",
              "human successes / push"]
    rows = [[alg, f"{_mean(rs, lambda r: r.summary['rohe']):.4f}",
             f"{_mean(rs, lambda r: r.summary['successes']):.1f} "
             f"({_mean(rs, lambda r: r.parts['policy_successes']):.1f} + "
             f"{_mean(rs, lambda r: r.parts['human_successes']):.1f})",
             f"{_mean(rs, lambda r: r.summary['human_actions']):.1f}",
             f"{_rate(rs, 'policy_successes', 'policy_pushes'):.3f}",
             f"{_rate(rs, 'policy_violations', 'policy_pushes'):.3f}",
             f"{_rate(rs, 'human_successes', 'human_pushes'):.3f}"]
            for alg, rs in groups.items()]
    table = Table("rohe", "ROHE and its parts (mean over trials; per push: pooled)",
                  header, rows)
    if PAPER_FIRST not in groups:
        return table
    cur = groups[PAPER_FIRST]
    c_rohe = _mean(cur, lambda r: r.summary["rohe"])
    c_succ = _mean(cur, lambda r: r.summary["successes"])
    c_hum = _mean(cur, lambda r: r.summary["human_actions"])
    for alg, rs in groups.items():
        rohe = _mean(rs, lambda r: r.summary["rohe"])
        if alg == PAPER_FIRST or rohe < c_rohe:
            continue
        succ = _mean(rs, lambda r: r.summary["successes"])
        hum = _mean(rs, lambda r: r.summary["human_actions"])
        s_factor = succ / c_succ if c_succ else float("inf")
        h_factor = (1 + c_hum) / (1 + hum)
        decides = ("human actions" if abs(np.log(max(h_factor, 1e-9)))
                   >= abs(np.log(max(s_factor, 1e-9))) else "successes")
        table.notes.append(
            f"{alg} is not below C.U.R. by ROHE ({rohe:.4f} against {c_rohe:.4f}), "
            f"the reverse of the paper's ordering. Its successes are {s_factor:.2f}x "
            f"C.U.R.'s ({succ:.1f} against {c_succ:.1f}) and its human actions "
            f"{hum:.1f} against {c_hum:.1f}, a factor {h_factor:.2f} in its favour in "
            f"ROHE's denominator: {decides} decide it. Per push, its policy succeeds "
            f"{_rate(rs, 'policy_successes', 'policy_pushes'):.3f} and violates "
            f"{_rate(rs, 'policy_violations', 'policy_pushes'):.3f} (C.U.R.'s "
            f"{_rate(cur, 'policy_successes', 'policy_pushes'):.3f} and "
            f"{_rate(cur, 'policy_violations', 'policy_pushes'):.3f}); the humans' "
            f"teleop pushes succeed {_rate(cur, 'human_successes', 'human_pushes'):.3f} "
            f"per push under C.U.R.")
    return table


def rohe_section(runs: list[RunRecord]) -> str:
    """ROHE and its parts as Markdown (``rohe_table``)."""
    return rohe_table(runs).markdown()


def _config(path: Path) -> dict[str, Any]:
    import tomllib

    cfg = path / "config.toml"
    return tomllib.loads(cfg.read_text()) if cfg.exists() else {}


def _groups(runs: list[RunRecord]) -> dict[str, list[RunRecord]]:
    """Runs by row/line: a sweep's points in its grid's order (run.json
    ``sweep.index``), else in the order they come; each group's runs by trial."""
    ordered = sorted(runs, key=lambda r: r.grid_index) if any(
        "sweep" in r.meta for r in runs) else runs
    groups: dict[str, list[RunRecord]] = {}
    for r in ordered:
        groups.setdefault(r.group, []).append(r)
    return {g: sorted(rs, key=lambda r: r.trial) for g, rs in groups.items()}


def mean_std_table(runs: list[RunRecord], metrics: tuple[str, ...] = METRICS,
                   key: str = "learning", title: str = "") -> Table:
    """Mean +- std (ddof 0) over trials per group and metric: the paper's tables. A
    sweep's CSV also has each point's values, numbers as numbers."""
    groups = _groups(runs)
    first = "point" if any(r.group != r.algorithm for r in runs) else "algorithm"
    fields, values = _sweep_columns(groups)
    rows: list[list[str]] = []
    csv_rows: list[list[Any]] = [[first, *fields, "trials"]
                                 + [f"{m}_{s}" for m in metrics for s in ("mean", "std")]]
    for alg, rs in groups.items():
        cells, row = [], [alg, *values.get(alg, []), len(rs)]
        for m in metrics:
            v = np.array([float(r.summary[m]) for r in rs])
            mean, std = float(v.mean()), float(v.std(ddof=0))
            fmt = "{:.4f}" if m == "rohe" else "{:.1f}"
            cells.append(f"{fmt.format(mean)} ± {fmt.format(std)}")
            row += [round(mean, 6), round(std, 6)]
        rows.append([alg, str(len(rs)), *cells])
        csv_rows.append(row)
    return Table(key, title, [first, "trials", *metrics], rows, csv_rows=csv_rows)


def _sweep_columns(groups: dict[str, list[RunRecord]]) -> tuple[list[str], dict[str, list[Any]]]:
    """The grid's fields and each point's values (numbers as numbers) for the CSV, when
    every group is a point of one grid; else nothing."""
    values = {g: rs[0].meta.get("sweep", {}).get("values") for g, rs in groups.items()}
    if not all(values.values()) or len({tuple(v) for v in values.values()}) != 1:
        return [], {}
    return list(next(iter(values.values()))), {g: list(v.values()) for g, v in values.items()}


def _plot(runs: list[RunRecord]) -> bytes:
    """The five cumulative curves, one line per group, shaded one standard deviation
    over trials (the paper's figures): PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = _groups(runs)
    fig, axes = plt.subplots(1, len(METRICS), figsize=(4.2 * len(METRICS), 3.6))
    for ax, m in zip(axes, METRICS, strict=True):
        for alg, rs in groups.items():
            n = min(len(r.curves[m]) for r in rs)
            if n == 0:
                continue
            ys = np.stack([r.curves[m][:n] for r in rs])
            mean, std = ys.mean(0), ys.std(0)
            x = np.arange(1, n + 1)
            ax.plot(x, mean, label=alg)
            ax.fill_between(x, mean - std, mean + std, alpha=0.2)
        ax.set_title(TITLES[m])
        ax.set_xlabel("timestep")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()


def _reference(groups: dict[str, list[RunRecord]], asked: str | None, prefix: str = ""
               ) -> str | None:
    """The group the others are compared with: ``--reference`` (with the evaluation's
    prefix for the evaluation table), else C.U.R., else a sweep's first point."""
    from testbed.core.config import ConfigError

    if asked is not None:
        name = prefix + asked if prefix and not asked.startswith(prefix) else asked
        if name not in groups:
            if prefix:
                return None  # no evaluation of it: the evaluation table has no comparison
            raise ConfigError(f"--reference: no finished run of {asked!r} here; give one of "
                              f"{', '.join(groups)}")
        return name
    if prefix + PAPER_FIRST in groups:
        return prefix + PAPER_FIRST
    first = next(iter(groups.values()))[0]
    return first.group if "sweep" in first.meta and len(groups) > 1 else None


def learning_tables(runs: list[RunRecord], metrics: tuple[str, ...], reference: str | None,
                    prefix: str = "", kind: str = "learning") -> list[Table]:
    """After the table of means: the intervals (with any identical records under them)
    and the paired comparison against the reference."""
    groups = _groups(runs)
    first = "point" if any(r.group != r.algorithm for r in runs) else "algorithm"
    what = "evaluation" if prefix else ("sweep" if first == "point" else "learning")
    tables = [interval_table(f"{kind}-intervals", f"95% intervals ({what})", first,
                             {g: [r.summary for r in rs] for g, rs in groups.items()},
                             metrics)]
    ref = _reference(groups, reference, prefix)
    if ref is not None and len(groups) > 1:
        tables.append(paired_table(
            f"{kind}-paired", f"Paired against {ref} ({what})", first,
            {g: {r.trial: r.summary for r in rs} for g, rs in groups.items()}, ref,
            metrics, trial_label))
    same = identical_groups({g: {r.trial: r.digest for r in rs} for g, rs in groups.items()},
                            trial_label)
    tables[0].notes += same
    return tables


def write_report(dirs: list[Path], out: Path, reference: str | None = None) -> Report:
    """report.md, report.html and the CSVs of the finished runs in or below ``dirs``;
    ``reference``: the algorithm (or sweep point) the others are compared with."""
    from testbed.core.config import ConfigError

    found = find_runs(dirs)
    if not found:
        raise ConfigError(
            "RUN_OR_PROTOCOL_DIR: no run found (no steps.jsonl in or below the folders given)"
        )
    left_out = {p: why for p in found if (why := unfinished(p)) is not None}
    notes = []
    if left_out:
        notes.append(
            f"left out {len(left_out)} unfinished run(s) (resume with testbed trial --resume "
            "DIR, or run the protocol again): "
            + ", ".join(f"{p} ({why})" for p, why in left_out.items())
        )
    runs = [load_run(p) for p in found if p not in left_out]
    if not runs:
        raise ConfigError(f"RUN_OR_PROTOCOL_DIR: no finished run; {notes[0]}")
    out.mkdir(parents=True, exist_ok=True)
    sections = place_sequential(_sections(runs, reference), dirs)  # a protocol's until
    md = "\n".join(t.markdown() for t in sections) + "".join(f"\n{n}\n" for n in notes)
    for t in sections:
        if t.csv_rows:
            atomic_write_bytes(out / CSV_NAMES.get(t.key, f"report-{t.key}.csv"),
                               t.csv_text().encode())
        for name, content in t.files.items():
            atomic_write_bytes(out / name, content)
    atomic_write_bytes(out / "report.md", md.encode())
    learning = [r for r in runs if not r.algorithm.startswith(EVAL_PREFIX)]
    png = _plot(learning or runs)
    atomic_write_bytes(out / "curves.png", png)
    from testbed.results.report_html import report_page

    atomic_write_bytes(out / "report.html", report_page(sections, notes, png, runs).encode())
    return Report(out, md, runs, notes, sections)


CSV_NAMES = {"learning": "report.csv", "eval": "report-eval.csv"}
"""The two CSVs scripts read since before the intervals (their names kept)."""


def _sections(runs: list[RunRecord], reference: str | None) -> list[Table]:
    """Every table of the report, in the page's order."""
    learning = [r for r in runs if not r.algorithm.startswith(EVAL_PREFIX)]
    evaluations = [r for r in runs if r.algorithm.startswith(EVAL_PREFIX)]
    tables: list[Table] = []
    if learning:
        tables.append(mean_std_table(learning))
        tables += learning_tables(learning, METRICS, reference)
        if all(r.group == r.algorithm for r in learning):  # not for sweeps
            tables.append(rohe_table(learning))
        groups = _groups(learning)
        tables.append(humans_table({g: [RunHumans(r.humans, r.human_counts,
                                                  r.human_estimates, r.human_profiles)
                                        for r in rs] for g, rs in groups.items()}))
    if evaluations:
        tables.append(mean_std_table(
            evaluations, EVAL_METRICS, key="eval",
            title="Evaluation (the paper's 8.3.4, Table 2): each final policy alone, "
                  "humans for hard resets only"))
        tables += learning_tables(evaluations, EVAL_METRICS, reference, EVAL_PREFIX, "eval")
        if learning:
            tables += gain_tables(learning, evaluations, reference or PAPER_FIRST, trial_label)
    tables.append(classes_table([(r.path.name, r.group, r.classes)
                                 for r in [*learning, *evaluations]]))
    from testbed.results.report_prediction import monitor_tables

    tables += monitor_tables([(g, [r.path for r in rs], rs[0].config)
                              for g, rs in _groups([*learning, *evaluations]).items()],
                             [r.path for r in learning if "monitor" in (
                                 r.algorithm, r.meta.get("options", {}).get("algorithm"))])
    return tables
