"""The report's sequential table: what a protocol with ``until`` settled, after which
trial, its e-values, its confidence sequences, and the trials it saved against the fixed
design.

Why a table of its own, read from the protocol's ``sequential.json`` rather than
recomputed from the runs: it says what the protocol *decided* when it ran (with the
``until`` it ran under, which the runs' records do not carry). Each pair is read at the
family's per-comparison alpha (the protocol's alpha split by Bonferroni over its primary
comparisons and those of the protocols it shares reference runs with, ``until.family``);
the primary endpoints get the sequential claims (settled, the anytime p, the confidence
sequence excluding 0), the secondary ones are flagged as descriptive. A record written
before endpoints were declared is read with every pair primary and no family. Every
table that prints a fixed-n figure (a t or bootstrap interval, a sign-flip p) is flagged
(:func:`flag_fixed_n`): those assume a number of trials fixed in advance, which optional
stopping is not.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from testbed.results.report_tables import Table
from testbed.results.sequential import (
    CAP,
    FORMAT,
    RECORD,
    anytime_p,
    bets,
    confidence_sequence,
    fewest_trials,
    reachable,
)

__all__ = ["FIXED_N_MARK", "Family", "family_of", "flag_fixed_n", "place_sequential",
           "sequential_table", "sequential_tables"]

FIXED_N_MARK = "†"
"""The mark on a fixed-n figure's column in a report of a protocol that stopped on the
data (:func:`flag_fixed_n`)."""
FIXED_N_COLUMNS = ("95% interval", "sign-flip p")
RUN_INTERVAL_TABLES = ("prediction-auroc", "prediction-ap", "prediction-lead")
"""Tables with intervals over runs (their number chosen with the trials): a note only."""

RATIOS = frozenset({"rohe"})


def _signed(x: float, metric: str) -> str:
    return f"{x:+.4f}" if metric in RATIOS else f"{x:+.1f}"


def _e(x: float) -> str:
    return f"{x:.3g}"


@dataclass(frozen=True)
class Family:
    """How a record's alpha is split: its primary pairs and the family they belong to."""

    alpha: float
    """The protocol's declared (family-wise) alpha."""
    comparisons: int
    """Primary comparisons in the family: this protocol's and ``shared``'s."""
    primary: tuple[str, ...]
    shared: dict[str, int]
    """Other protocols sharing the reference runs, each with its primary comparisons."""
    ran_at: float
    """The alpha the protocol's decision used per pair."""
    declared: bool
    """False: a record from before endpoints were declared (every pair primary)."""

    @property
    def per_comparison(self) -> float:
        return self.alpha / self.comparisons


def family_of(rec: dict[str, Any]) -> Family:
    """The alpha split of a ``sequential.json`` (defaults for a record without one)."""
    pairs = tuple(rec["pairs"])
    if "comparisons" in rec:
        return Family(float(rec["family_alpha"]), max(1, int(rec["comparisons"])),
                      tuple(rec["primary"]), dict(rec.get("family", {})),
                      float(rec["alpha"]), True)
    return Family(float(rec["alpha"]), max(1, len(pairs)), pairs, {}, float(rec["alpha"]),
                  False)


@dataclass(frozen=True)
class _Read:
    """One pair read at the per-comparison alpha."""

    settled: int | None
    direction: int
    status: str
    best: float
    low: float
    high: float


def _read(diffs: list[float], es: list[float], alpha: float, max_trials: int) -> _Read:
    hit = [k for k, e in enumerate(es) if e >= 1 / alpha]
    best = reachable(es[-1] if es else 1.0, max_trials - len(es))
    cs = confidence_sequence(diffs, alpha) if diffs else None
    low, high = (math.nan, math.nan) if cs is None else (float(cs.low[-1]), float(cs.high[-1]))
    if hit:
        b = bets(diffs)
        k = hit[0]
        return _Read(k + 1, 1 if b.up[k] >= b.down[k] else -1, "settled", best, low, high)
    return _Read(None, 0, "cannot be settled" if best < 1 / alpha else "open", best, low,
                 high)


def _cs(r: _Read) -> str:
    if math.isnan(r.low):
        return "-" if math.isnan(r.high) else "empty"
    return f"[{r.low:+.3f}, {r.high:+.3f}]"


def _settled(r: _Read, reference: str) -> str:
    k = r.settled
    if k is None:
        return "-"
    side = "above" if r.direction > 0 else "below"
    return f"after {k} trial{'s' if k != 1 else ''} (t{k - 1}): {side} {reference}"


def _status(r: _Read, max_trials: int, primary: bool) -> str:
    if not primary:
        return "secondary: no sequential claim"
    if r.status == "cannot be settled":
        reach = "" if not math.isfinite(r.best) else f": at most {_e(r.best)} reachable"
        return f"cannot be settled within {max_trials} trials{reach}"
    return r.status


def sequential_table(rec: dict[str, Any], key: str = "sequential",
                     where: str = "") -> Table:
    """The table of one ``sequential.json`` (:func:`testbed.results.sequential.record`)."""
    ref, metric = str(rec["reference"]), str(rec["metric"])
    max_trials = int(rec["max_trials"])
    fam = family_of(rec)
    alpha = fam.per_comparison
    level = f"{1 - alpha:.4g}"
    header = ["algorithm", "endpoint", f"per trial (minus {ref})", "e-value after each trial",
              "settled", "e-value now (max)", "anytime p (1 / max e)",
              f"confidence sequence ({level}, clipped scale)", "status", "trials saved"]
    rows: list[list[str]] = []
    csv_rows: list[list[Any]] = [["algorithm", "endpoint", "metric", "trials",
                                  "settled_after", "direction", "e_value", "e_max",
                                  "anytime_p", "family_adjusted_p", "per_comparison_alpha",
                                  "cs_low", "cs_high", "status", "trials_saved", "e_values",
                                  "differences"]]
    for name, pair in rec["pairs"].items():
        diffs = [float(d) for d in pair["differences"]]
        es = [float(e) for e in pair["e_values"]]
        primary = name in fam.primary
        r = _read(diffs, es, alpha, max_trials)
        saved = max_trials - r.settled if (r.settled and primary) else None
        p = anytime_p(es) if es else math.nan
        rows.append([
            name, "primary" if primary else "secondary",
            ", ".join(f"t{k}: {_signed(d, metric)}" for k, d in enumerate(diffs)) or "-",
            ", ".join(f"t{k}: {_e(e)}" for k, e in enumerate(es)) or "-",
            _settled(r, ref) if primary else "-",
            f"{_e(es[-1])} ({_e(max(es))})" if es else "-",
            "-" if math.isnan(p) else f"{p:.3g}", _cs(r), _status(r, max_trials, primary),
            "-" if saved is None else str(saved)])
        csv_rows.append([name, "primary" if primary else "secondary", metric, len(diffs),
                         r.settled or "", r.direction, es[-1] if es else "",
                         max(es) if es else "", "" if math.isnan(p) else p,
                         "" if math.isnan(p) or not primary else min(1.0, fam.comparisons * p),
                         alpha, "" if math.isnan(r.low) else r.low,
                         "" if math.isnan(r.high) else r.high,
                         "secondary" if not primary else r.status,
                         "" if saved is None else saved,
                         " ".join(f"{e:.6g}" for e in es), " ".join(f"{d:.6g}" for d in diffs)])
    title = (f"Sequential test{where}: each algorithm against {ref} on {metric}, "
             f"settled at e-value >= {_e(1 / alpha)} (per-comparison alpha {alpha:.3g})")
    return Table(key, title, header, rows, _notes(rec, fam), csv_rows)


def _notes(rec: dict[str, Any], fam: Family) -> list[str]:
    done, minimum = int(rec["trials_done"]), int(rec["min_trials"])
    max_trials = int(rec["max_trials"])
    algorithms = len(rec["pairs"]) + 1
    saved = max(0, max_trials - done)
    if rec.get("stop"):
        decided = (f"The protocol stopped after {done} trial{'s' if done != 1 else ''} "
                   f"(at least {minimum}, at most {max_trials}): {rec.get('why')}. Against "
                   f"the fixed design of {max_trials} trials it saved {saved} trial"
                   f"{'s' if saved != 1 else ''} ({saved * algorithms} runs of "
                   f"{algorithms} algorithms, and their evaluations).")
    else:
        decided = (f"{done} trial{'s' if done != 1 else ''} finished (at least {minimum}, "
                   f"at most {max_trials}); not decided yet: run the protocol again to go on.")
    if not math.isclose(fam.ran_at, fam.per_comparison):
        decided += (f" It decided at alpha {fam.ran_at:.3g} per pair; this table reads "
                    f"every pair at the family's per-comparison alpha "
                    f"{fam.per_comparison:.3g}, so a pair it called settled may not be here.")
    notes = [decided, _alpha_note(fam, rec)]
    secondary = [n for n in rec["pairs"] if n not in fam.primary]
    if secondary:
        notes.append(
            f"Secondary endpoint{'s' if len(secondary) > 1 else ''}: {', '.join(secondary)}"
            " (against the primary, " + ", ".join(fam.primary) + "). The protocol's "
            "stopping did not wait for them and they are outside the alpha split: their "
            "e-values, anytime p and confidence sequence are descriptive, and no sequential "
            "claim (settled, a direction) is made on them.")
    notes += [_method_note(fam, rec), _cs_note(fam.per_comparison)]
    return notes


def _alpha_note(fam: Family, rec: dict[str, Any]) -> str:
    """The family, its Bonferroni split, and the fewest trials at the split."""
    own = len(fam.primary)
    shared = "".join(f", {n} ({k})" for n, k in fam.shared.items())
    where = (f"{own} primary comparison{'s' if own != 1 else ''} here ("
             + ", ".join(fam.primary) + f"){shared}")
    text = (f"Alpha {fam.alpha:g} split by Bonferroni over the family's {fam.comparisons} "
            f"primary comparison{'s' if fam.comparisons != 1 else ''}: {where}"
            + (" (protocols that share its reference runs)" if fam.shared else "")
            + f"; per-comparison alpha {fam.alpha:g} / {fam.comparisons} = "
            f"{fam.per_comparison:.3g}, settled at e-value >= {_e(1 / fam.per_comparison)}.")
    if not fam.declared:
        text += (" This record predates declared endpoints (until.primary, until.family): "
                 "every pair is read as primary, and no other protocol as sharing its "
                 "reference runs.")
    n = fewest_trials(fam.per_comparison)
    at = (f"{n} trial{'s' if n != 1 else ''}" if n is not None
          else "more trials than any design allows")
    text += (f" The fewest trials this design can settle a pair in at "
             f"{fam.per_comparison:.3g}: {at} (that many differences all of one sign, the "
             "most evidence a trial can give)")
    if n is not None and n > int(rec["max_trials"]):
        text += f", more than max_trials ({rec['max_trials']}): no pair can be settled"
    return text + "."


def _method_note(fam: Family, rec: dict[str, Any]) -> str:
    return ("Anytime-valid, by betting (Waudby-Smith and Ramdas, \"Estimating means of "
            "bounded random variables by betting\", JRSS-B 2023; Shafer and Vovk's testing "
            "by betting): per pair, two wealths bet each trial on the sign of its "
            "difference, one that the algorithm is above the reference, one below, each "
            "difference divided by half the mean |difference| of the trials before it and "
            "clipped to [-1, 1] (the first: its sign); the e-value is their average. Under "
            "\"no difference\" (each difference's sign a fair coin, the sign-flip test's "
            "null) it is a nonnegative martingale, so by Ville's inequality it reaches "
            "1/alpha with probability at most alpha however often it is looked at: the "
            "protocol may stop on it, or be extended, and the answer holds. Anytime p = "
            "min(1, 1 / the largest e-value so far), valid whenever the protocol stopped, "
            "unlike a fixed-n p-value; compare it with the per-comparison alpha (the CSV's "
            f"family_adjusted_p, {fam.comparisons} x p, with alpha {fam.alpha:g}). \"Cannot "
            "be settled\": one trial can at most multiply the e-value by "
            f"{1 + float(rec.get('cap', CAP)):g}, and not even that on every trial left "
            "reaches the threshold. Trials saved per primary pair: the fixed design's "
            "trials after the pair was settled.")


def _cs_note(alpha: float) -> str:
    return (f"Confidence sequence ({1 - alpha:.4g}, the per-comparison level): the betting "
            "confidence sequence of Waudby-Smith and Ramdas (2023) for a bounded mean, on "
            "the e-value's own clipped scale: the mean of X_k = clip(D_k / s_k, -1, 1), "
            "s_k half the mean |difference| of the trials before k (the first trial: its "
            "sign). +1: above the reference by at least that scale in every trial; -1: "
            "below; 0: no lean either way. Each candidate mean m is bet against as the "
            "e-value bets against 0 (the same bets on X_k - m), and the set is every m no "
            "bet has yet made 1/alpha of, through every trial so far (on a grid of step "
            "0.001, widened by a step). Valid at every trial at once, so whenever the "
            "protocol stopped, if each trial's clipped outcome has one mean given the "
            "trials before; at 0 it needs only the e-value's null, and it excludes 0 "
            "exactly when the pair is settled. Not in the metric's units: the scale moves "
            "with the trials, so it bounds how consistently and which way the algorithm "
            "differs, not by how much.")


FIXED_N_NOTE = (f"{FIXED_N_MARK} fixed-n figures, not valid after optional stopping: this "
                "protocol ran with `until` and chose its number of trials from the data, so "
                "{what} (for a number of trials fixed in advance) overstate the evidence. "
                "Read the sequential table's e-value, anytime p and confidence sequence "
                "instead.")


def flag_fixed_n(table: Table) -> Table:
    """``table`` with its fixed-n columns marked and a note first: a paired table's
    sign-flip p-value and t interval, an intervals table's every metric (t or bootstrap
    intervals of the mean over trials), a prediction table's intervals over runs (the
    note only). Flagged, not dropped: the figures stay readable (and scripts keep their
    CSV), marked as what they are."""
    if table.key.endswith("-paired"):
        header = [f"{h} {FIXED_N_MARK}" if h in FIXED_N_COLUMNS else h for h in table.header]
        what = "the sign-flip p-value and the 95% interval of the difference"
    elif table.key.endswith("-intervals"):
        header = [h if i < 2 else f"{h} {FIXED_N_MARK}" for i, h in enumerate(table.header)]
        what = "the 95% intervals of the means over trials (t, or a bootstrap)"
    elif table.key in RUN_INTERVAL_TABLES:
        header = list(table.header)
        what = "the 95% intervals over runs (the runs came with the trials)"
    else:
        return table
    return Table(table.key, table.title, header, table.rows,
                 [FIXED_N_NOTE.format(what=what), *table.notes], table.csv_rows, table.files)


def sequential_tables(dirs: Sequence[Path]) -> list[Table]:
    """One table per folder of ``dirs`` holding a ``sequential.json`` (a protocol run
    with ``until``); a file this build cannot read gets a table that says so."""
    found = [d / RECORD for d in dirs if (d / RECORD).is_file()]
    tables = []
    for i, path in enumerate(found):
        key = "sequential" if i == 0 else f"sequential-{i}"
        where = f" ({path.parent})" if len(found) > 1 else ""
        try:
            rec = json.loads(path.read_text())
            if rec.get("format") != FORMAT:
                raise ValueError(f"format {rec.get('format')!r}, not {FORMAT!r}")
            tables.append(sequential_table(rec, key, where))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            tables.append(Table(key, f"Sequential test{where}", ["file"], [[str(path)]],
                                [f"{path} cannot be read by this build ({exc})."]))
    return tables


def place_sequential(tables: list[Table], dirs: Sequence[Path]) -> list[Table]:
    """``tables`` with the sequential tables of ``dirs`` right after the learning
    comparison (the paired table, else the intervals, else at the end), and every
    table's fixed-n figures flagged (:func:`flag_fixed_n`)."""
    extra = sequential_tables(dirs)
    if not extra:
        return tables
    tables = [flag_fixed_n(t) for t in tables]
    keys = [t.key for t in tables]
    for anchor in ("learning-paired", "learning-intervals"):
        if anchor in keys:
            at = keys.index(anchor) + 1
            return [*tables[:at], *extra, *tables[at:]]
    return [*tables, *extra]
