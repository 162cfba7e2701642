"""The report's tables beyond mean +- std: intervals, paired comparisons, the humans,
identical records. Each is a :class:`Table`, written to Markdown and to the HTML page
from the same cells, and the numbers behind it to a CSV for scripts.

Why one shape: report.md, report.html and the CSVs must say the same thing; building
every table once, as rows of cells, and rendering it twice keeps them from drifting.
The statistics are :mod:`testbed.results.intervals`; the per-human counts
:mod:`testbed.results.report_humans`.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
from collections.abc import Callable, Hashable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from testbed.results.intervals import BOOTSTRAP_MIN_TRIALS, Interval, interval, paired
from testbed.results.report_humans import RunHumans, merge

__all__ = ["Table", "humans_table", "identical_groups", "interval_table", "paired_table",
           "steps_digest"]


@dataclass
class Table:
    """One table of the report: a title, a header, rows of cells, notes under it."""

    key: str
    """A stable id (the HTML anchor, the CSV's name, what tests look for)."""
    title: str
    header: list[str]
    rows: list[list[str]]
    notes: list[str] = field(default_factory=list)
    csv_rows: list[list[Any]] = field(default_factory=list)
    """The numbers behind the cells, header first (empty: no CSV)."""
    files: dict[str, bytes] = field(default_factory=dict)
    """Other files that come with the table (name -> content), written beside the CSVs:
    the failure head fitted on the runs (``failure-head.json``)."""

    def markdown(self) -> str:
        lines = [f"{self.title}\n"] if self.title else []
        lines += ["| " + " | ".join(self.header) + " |", "|" + "---|" * len(self.header)]
        lines += ["| " + " | ".join(row) + " |" for row in self.rows]
        text = "\n".join(lines) + "\n"
        return text + "".join(f"\n{n}\n" for n in self.notes)

    def csv_text(self) -> str:
        buf = io.StringIO()
        csv.writer(buf).writerows(self.csv_rows)
        return buf.getvalue()


RATIOS = frozenset({"rohe", "learning_gain"})
"""Metrics that are ratios (four decimals); the others are counts."""


def _fmt(metric: str) -> str:
    return "{:.4f}" if metric in RATIOS else "{:.1f}"


def _signed(x: float, metric: str) -> str:
    return f"{x:+.4f}" if metric in RATIOS else f"{x:+.1f}"


def _cell(iv: Interval, metric: str) -> str:
    f = _fmt(metric)
    if iv.method in ("none", "one"):
        return f.format(iv.mean) + " (one trial)" if iv.method == "one" else "-"
    return f"{f.format(iv.mean)} [{f.format(iv.low)}, {f.format(iv.high)}]"


def method_note(counts: Sequence[int]) -> str:
    """What the intervals are, and which rule these trial counts fell under."""
    used = sorted(set(counts))
    def rule(n: int) -> str:
        return ("no interval" if n < 2 else "BCa bootstrap" if n >= BOOTSTRAP_MIN_TRIALS
                else "t")

    kinds = ", ".join(f"{n} trial{'s' if n != 1 else ''}: {rule(n)}" for n in used)
    return (f"95% intervals of the mean over trials: Student's t with n - 1 degrees of "
            f"freedom for fewer than {BOOTSTRAP_MIN_TRIALS} trials (a bootstrap of so few "
            f"trials has too few distinct resamples and is too narrow), a BCa bootstrap "
            f"over trials (9999 resamples, seeded) from {BOOTSTRAP_MIN_TRIALS} on; here "
            f"{kinds}. All trials of a row equal: the interval is that value. A t interval "
            f"of a count can reach below 0: that is the width so few trials allow, not a "
            f"value the count can take.")


def interval_table(key: str, title: str, first: str,
                   groups: Mapping[str, Sequence[Mapping[str, float]]],
                   metrics: Sequence[str]) -> Table:
    """Per group (algorithm or sweep point) and metric: the mean with its 95% interval.
    ``groups``: name -> one summary per trial."""
    rows, csv_rows = [], [[first, "trials"] + [f"{m}_{s}" for m in metrics
                                              for s in ("mean", "low", "high")]]
    counts = []
    for name, summaries in groups.items():
        ivs = [interval([float(s[m]) for s in summaries]) for m in metrics]
        counts.append(len(summaries))
        rows.append([name, str(len(summaries))] + [_cell(iv, m)
                                                   for iv, m in zip(ivs, metrics, strict=True)])
        csv_rows.append([name, len(summaries)] + [_num(x) for iv in ivs
                                                  for x in (iv.mean, iv.low, iv.high)])
    return Table(key, title, [first, "trials", *metrics], rows, [method_note(counts)],
                 csv_rows)


def _num(x: float) -> float | str:
    return "" if math.isnan(x) else round(float(x), 6)


def paired_table(key: str, title: str, first: str,
                 groups: Mapping[str, Mapping[Hashable, Mapping[str, float]]],
                 reference: str, metrics: Sequence[str],
                 key_label: Callable[[Hashable], str]) -> Table:
    """Every group against ``reference``, pair by pair (``groups``: name -> trial key ->
    summary): the differences, their mean and interval, the exact sign-flip p-value."""
    ref = groups[reference]
    header = [first, "metric", f"per trial (minus {reference})", "mean difference",
              "95% interval", "sign-flip p", "pairs"]
    rows: list[list[str]] = []
    csv_rows: list[list[Any]] = [[first, "metric", "pairs", "mean_difference", "low", "high",
                                  "p_value", "differences"]]
    notes: list[str] = []
    floors: set[int] = set()
    for name, by_key in groups.items():
        if name == reference:
            continue
        for m in metrics:
            cmp = paired({k: float(s[m]) for k, s in by_key.items()},
                         {k: float(s[m]) for k, s in ref.items()})
            f = _fmt(m)
            per = ", ".join(f"{key_label(k)}: {_signed(d, m)}" for k, d in
                            zip(cmp.keys, cmp.diffs, strict=True))
            iv = cmp.difference
            ci = ("-" if iv.method in ("none", "one")
                  else f"[{f.format(iv.low)}, {f.format(iv.high)}]")
            p = "-" if math.isnan(cmp.p_value) else f"{cmp.p_value:.3f}"
            rows.append([name, m, per or "-", "-" if math.isnan(iv.mean) else
                         _signed(iv.mean, m), ci, p, str(len(cmp.diffs))])
            csv_rows.append([name, m, len(cmp.diffs), _num(iv.mean), _num(iv.low),
                             _num(iv.high), _num(cmp.p_value),
                             " ".join(f"{d:.6g}" for d in cmp.diffs)])
            floors.add(len(cmp.diffs))
            if m == metrics[0] and cmp.unpaired:
                notes.append(f"{name}: {', '.join(key_label(k) for k in cmp.unpaired)} "
                             f"{'has' if len(cmp.unpaired) == 1 else 'have'} a finished run "
                             f"of only one of {name} and {reference}, and "
                             f"{'is' if len(cmp.unpaired) == 1 else 'are'} left out of "
                             "this comparison (a difference needs both runs).")
    notes.insert(0, _paired_note(reference, sorted(floors)))
    return Table(key, title, header, rows, notes, csv_rows)


def _paired_note(reference: str, pair_counts: Sequence[int]) -> str:
    floors = "; ".join(f"{n} pairs: {2.0 / 2 ** n:.4g}" if n > 1 else f"{n} pair: 1"
                       for n in pair_counts if n > 0)
    return (f"Paired by trial: the runs of one trial share theta_0 and the trial's seed, "
            f"so each difference is one trial's run minus {reference}'s. The sign-flip "
            f"p-value is exact (every one of the 2^n sign patterns of the differences): "
            f"the chance, were there no difference, of a mean difference as far from 0. "
            f"Its smallest possible value is 2 / 2^n ({floors}): with 3 trials no "
            f"comparison can reach p < 0.05 however large the difference, so read the "
            f"interval for the size and more trials for a test. The interval of the mean "
            f"difference follows the rule of the intervals above.")


HUMAN_HEADER = ["algorithm", "human", "teleops", "resets", "steps held", "pushes",
                "success / push", "violations (teleop)", "to first push (steps)",
                "to first push (s)", "reset took (steps)", "skill est. (profile)",
                "latency est. (profile)", "reset est. (profile)"]
_ESTIMATE_CSV = ["skill_estimate", "skill_profile", "latency_estimate", "latency_profile",
                 "reset_estimate", "reset_profile"]


def _mean(xs: Sequence[float], fmt: str) -> str:
    return "-" if not xs else fmt.format(sum(xs) / len(xs))


def _estimates(runs: Sequence[RunHumans], name: str) -> list[tuple[float, Any]]:
    """(estimate, profile) of skill, latency and reset for human ``name``: the mean of
    its runs' end-of-run estimates, and its profile's figure (when every run's profile
    agrees; else None). NaN and None where nothing was estimated or scripted."""
    ests = [r.estimates[r.names.index(name)] for r in runs
            if name in r.names and len(r.estimates) == len(r.names)]
    profs = {r.profiles[r.names.index(name)] for r in runs
             if name in r.names and len(r.profiles) == len(r.names)}
    prof = profs.pop() if len(profs) == 1 else None
    out: list[tuple[float, Any]] = []
    for est, truth in (("skill", "skill"), ("latency_steps", "latency"),
                       ("reset_steps", "reset_steps")):
        value = (sum(getattr(e, est) for e in ests) / len(ests)) if ests else math.nan
        out.append((value, None if prof is None else getattr(prof, truth)))
    return out


def _beside(value: float, truth: Any, fmt: str) -> str:
    """``0.342 (1)``: an estimate with the profile's figure beside it."""
    if math.isnan(value):
        return "-"
    return fmt.format(value) + ("" if truth is None else f" ({truth:g})")


def humans_table(per_group: Mapping[str, Sequence[RunHumans]]) -> Table:
    """Per algorithm and human (by name): their interventions, time held, time to act,
    and their pushes' outcomes, summed over the trials; then what the fleet's own model
    estimated of them (mean over the trials' ends) beside their scripted profile
    (``per_group``: name -> its runs' humans)."""
    rows: list[list[str]] = []
    csv_rows: list[list[Any]] = [[h.replace(" / ", "_per_").replace(" ", "_")
                                  for h in HUMAN_HEADER[:-3]] + _ESTIMATE_CSV]
    for group, runs in per_group.items():
        names: list[str] = []
        for run in runs:
            names += [n for n in run.names if n not in names]
        for name in names:
            c = merge([run.counts[run.names.index(name)] for run in runs
                       if name in run.names])
            est = _estimates(runs, name)
            rate = "-" if math.isnan(c.success_rate) else f"{c.success_rate:.3f}"
            cells = [group, name, str(c.teleops), str(c.resets), str(c.steps_held),
                     str(c.pushes), rate, str(c.violations),
                     _mean(c.first_push_steps, "{:.2f}"), _mean(c.first_push_s, "{:.2f}"),
                     _mean(c.reset_steps, "{:.2f}"),
                     *(_beside(v, t, f) for (v, t), f in zip(est, ("{:.3f}", "{:.2f}",
                                                                  "{:.2f}"), strict=True))]
            rows.append(cells)
            csv_rows.append([group, name, c.teleops, c.resets, c.steps_held, c.pushes,
                             _num(c.success_rate), c.violations,
                             *(_num(sum(x) / len(x)) if x else "" for x in
                               (c.first_push_steps, c.first_push_s, c.reset_steps)),
                             *(x for v, t in est for x in (_num(v), "" if t is None else t))])
    notes = ["Summed over each algorithm's trials. An intervention starts where a human "
             "is put on an arm; \"to first push\" is from that step to their first push "
             "(0: they pushed on the step they were assigned), in steps and in the "
             "seconds their console measured (scripted humans: steps only; '-': no "
             "console measured it); \"reset took\" is the steps from the "
             "assignment to the confirmation. A push is a teleop step the host executed; "
             "its success and violation are that step's.",
             "est.: what the fleet's own model (testbed/fleet/operators.py; the matched "
             "allocation ranks humans by it) said of the human at the end of each run, "
             "averaged over the trials: successes per teleop push, steps to the first "
             "push, steps a reset took, each shrunk towards the fleet's pooled figure "
             "(a human with few pushes reads near the average). In parentheses, a "
             "scripted human's profile: its skill is the chance a push is the expert's "
             "(the expert's own pushes succeed only part of the time, so compare the "
             "order of the estimates, not their values, with it), its latency in steps, "
             "and its reset, t_R + latency."]
    return Table("humans", "The humans (per algorithm, summed over trials)", HUMAN_HEADER,
                 rows, notes, csv_rows)


BEHAVIOUR = ("robot", "mode", "human", "action", "success", "violation", "refused",
             "served")
"""What an arm did at a step: who acted, what, and what came of it. Not its ``key``
(each algorithm's keys have their own shape: R's and C.R.'s differ even when they pick
the same arms), nor the learner's signals or any timing."""


def steps_digest(rows: Iterable[Mapping[str, Any]]) -> str:
    """SHA-256 of what a run's fleet did, step by step (``BEHAVIOUR`` of every arm,
    faults, away humans, released interventions), from the rows already read: equal
    digests, the same run, whatever the algorithm's keys said and however long the
    steps took."""
    h = hashlib.sha256()
    for row in rows:
        kept = {"t": row.get("t"), "faults": row.get("faults"), "away": row.get("away"),
                "released": row.get("released"),
                "robots": [{k: arm.get(k) for k in BEHAVIOUR}
                           for arm in row.get("robots", [])]}
        h.update(json.dumps(kept, sort_keys=True).encode())
    return h.hexdigest()


def identical_groups(digests: Mapping[str, Mapping[Hashable, str]],
                     label: Callable[[Hashable], str] = str) -> list[str]:
    """One line per pair of groups whose runs have identical records in every trial they
    share: their comparison tests nothing this run can show."""
    names = list(digests)
    lines = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            common = [k for k in digests[a] if k in digests[b]]
            same = [k for k in common if digests[a][k] == digests[b][k]]
            if common and len(same) == len(common):
                lines.append(f"IDENTICAL RECORDS: {a} and {b} did the same, step for step "
                             f"(every arm's mode, human, push and outcome), in all "
                             f"{len(common)} trial(s) they share: what tells them apart "
                             "never happened in these runs, so this report cannot "
                             "compare them.")
            elif same:
                lines.append(f"Same records in part: {a} and {b} did the same, step for "
                             f"step, in {len(same)} of their {len(common)} shared trials "
                             f"({', '.join(label(k) for k in same)}); only the others "
                             "tell them apart.")
    return lines
