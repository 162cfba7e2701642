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
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from testbed.core.atomic import atomic_write_bytes
from testbed.records.metrics import cumulative, summarize
from testbed.records.run_dir import EVAL_PREFIX, evaluation_label
from testbed.records.steps import read_steps

METRICS = ("successes", "hard_resets", "idle_time", "human_actions", "rohe")
EVAL_METRICS = ("successes", "hard_resets", "idle_time")
TITLES = {
    "successes": "Cumulative successes",
    "hard_resets": "Cumulative hard resets",
    "idle_time": "Cumulative idle time",
    "human_actions": "Cumulative human actions",
    "rohe": "ROHE",
}


@dataclass
class RunRecord:
    path: Path
    algorithm: str
    num_humans: int
    summary: dict[str, Any]
    curves: dict[str, np.ndarray]
    parts: dict[str, int] = field(default_factory=dict)
    """Who made the successes and the violations (``rohe_parts``)."""
    group: str = ""
    """The table's row and the figure's line: the algorithm, or a sweep's point
    (run.json ``sweep.point``: ``humans.count-2``)."""

    def __post_init__(self) -> None:
        self.group = self.group or self.algorithm


@dataclass
class Report:
    folder: Path
    markdown: str
    runs: list[RunRecord]
    notes: list[str] = field(default_factory=list)
    """One line each: what the table leaves out (unfinished runs)."""


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
    num_humans = _num_humans(path)
    steps = read_steps(path / "steps.jsonl")
    summary = summarize(steps, algorithm=algorithm, num_humans=num_humans)
    curves = cumulative(steps, num_humans=num_humans)
    point = meta.get("sweep", {}).get("point", "")
    return RunRecord(path, algorithm, num_humans, summary, curves, rohe_parts(steps),
                     group=point)


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


def rohe_section(runs: list[RunRecord]) -> str:
    """Markdown: per algorithm, ROHE and its parts (successes by who pushed, human
    actions, the policy's successes and violations per push); then, for each
    algorithm whose ROHE is not below C.U.R.'s (the paper's ordering broken), one
    paragraph that says which part decides it, from these measurements: ROHE's ratio
    is (successes ratio) x ((1 + C.U.R.'s human actions) / (1 + its own)), and the
    larger factor decides."""
    groups = _groups(runs)
    head = ("| algorithm | ROHE | successes (policy + humans) | human actions | "
            "policy successes / push | policy violations / push | "
            "human successes / push |\n|---|---|---|---|---|---|---|\n")
    lines = []
    for alg, rs in groups.items():
        lines.append(
            f"| {alg} | {_mean(rs, lambda r: r.summary['rohe']):.4f} | "
            f"{_mean(rs, lambda r: r.summary['successes']):.1f} "
            f"({_mean(rs, lambda r: r.parts['policy_successes']):.1f} + "
            f"{_mean(rs, lambda r: r.parts['human_successes']):.1f}) | "
            f"{_mean(rs, lambda r: r.summary['human_actions']):.1f} | "
            f"{_rate(rs, 'policy_successes', 'policy_pushes'):.3f} | "
            f"{_rate(rs, 'policy_violations', 'policy_pushes'):.3f} | "
            f"{_rate(rs, 'human_successes', 'human_pushes'):.3f} |")
    text = ("ROHE and its parts (mean over trials; per push: pooled)\n\n" + head
            + "\n".join(lines) + "\n")
    if PAPER_FIRST not in groups:
        return text
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
        text += (
            f"\n{alg} is not below C.U.R. by ROHE ({rohe:.4f} against {c_rohe:.4f}), "
            f"the reverse of the paper's ordering. Its successes are {s_factor:.2f}x "
            f"C.U.R.'s ({succ:.1f} against {c_succ:.1f}) and its human actions "
            f"{hum:.1f} against {c_hum:.1f}, a factor {h_factor:.2f} in its favour in "
            f"ROHE's denominator: {decides} decide it. Per push, its policy succeeds "
            f"{_rate(rs, 'policy_successes', 'policy_pushes'):.3f} and violates "
            f"{_rate(rs, 'policy_violations', 'policy_pushes'):.3f} (C.U.R.'s "
            f"{_rate(cur, 'policy_successes', 'policy_pushes'):.3f} and "
            f"{_rate(cur, 'policy_violations', 'policy_pushes'):.3f}); the humans' "
            f"teleop pushes succeed {_rate(cur, 'human_successes', 'human_pushes'):.3f} "
            f"per push under C.U.R.\n")
    return text


def _num_humans(path: Path) -> int:
    import tomllib

    cfg = path / "config.toml"
    if cfg.exists():
        return int(tomllib.loads(cfg.read_text()).get("humans", {}).get("count", 2))
    return 2


def _groups(runs: list[RunRecord]) -> dict[str, list[RunRecord]]:
    """Runs by row/line, in the order they come (a sweep's file order)."""
    groups: dict[str, list[RunRecord]] = {}
    for r in runs:
        groups.setdefault(r.group, []).append(r)
    return groups


def _table(runs: list[RunRecord], metrics: tuple[str, ...] = METRICS) -> tuple[str, str]:
    groups = _groups(runs)
    first = "point" if any(r.group != r.algorithm for r in runs) else "algorithm"
    header = [first, "trials", *metrics]
    md = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow([first, "trials"] + [f"{m}_{s}" for m in metrics for s in ("mean", "std")])
    for alg, rs in groups.items():
        cells, row = [], [alg, len(rs)]
        for m in metrics:
            v = np.array([float(r.summary[m]) for r in rs])
            mean, std = float(v.mean()), float(v.std(ddof=0))
            fmt = "{:.4f}" if m == "rohe" else "{:.1f}"
            cells.append(f"{fmt.format(mean)} ± {fmt.format(std)}")
            row += [round(mean, 6), round(std, 6)]
        md.append("| " + " | ".join([alg, str(len(rs)), *cells]) + " |")
        w.writerow(row)
    return "\n".join(md) + "\n", buf.getvalue()


def _plot(runs: list[RunRecord], path: Path) -> None:
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
    atomic_write_bytes(path, buf.getvalue())


def write_report(dirs: list[Path], out: Path) -> Report:
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
    learning = [r for r in runs if not r.algorithm.startswith(EVAL_PREFIX)]
    evaluations = [r for r in runs if r.algorithm.startswith(EVAL_PREFIX)]
    md = ""
    if learning:
        md, csv_text = _table(learning)
        atomic_write_bytes(out / "report.csv", csv_text.encode())
    if learning and all(r.group == r.algorithm for r in learning):  # not for sweeps
        md += "\n" + rohe_section(learning)
    if evaluations:
        eval_md, eval_csv = _table(evaluations, EVAL_METRICS)
        md += ("\n" if md else "") + ("Evaluation (the paper's 8.3.4, Table 2): each final policy "
                                       "alone, humans for hard resets only\n\n") + eval_md
        atomic_write_bytes(out / "report-eval.csv", eval_csv.encode())
    md += "".join(f"\n{n}\n" for n in notes)
    atomic_write_bytes(out / "report.md", md.encode())
    _plot(learning or evaluations, out / "curves.png")
    return Report(out, md, runs, notes)
