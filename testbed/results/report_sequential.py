"""The report's sequential table: what a protocol with ``until`` settled, after which
trial, its e-values, and the trials it saved against the fixed design.

Why a table of its own, read from the protocol's ``sequential.json`` rather than
recomputed: it says what the protocol *decided* when it ran (with the ``until`` it ran
under, which the runs' records do not carry), and the e-values a reviewer checks the
decision against, with the anytime-valid p-value (1 / the largest e-value) and the
fewest trials the design can settle a pair in. The paired table beside it keeps the
fixed-design numbers, flagged (:func:`flag_fixed_n`): its sign-flip p-value and t
interval assume a number of trials fixed in advance, which optional stopping is not.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from testbed.results.report_tables import Table
from testbed.results.sequential import FORMAT, RECORD, anytime_p, fewest_trials

__all__ = ["FIXED_N_MARK", "flag_fixed_n", "place_sequential", "sequential_table",
           "sequential_tables"]

FIXED_N_MARK = "†"
"""The mark on a fixed-n figure's column in a report of a protocol that stopped on the
data (:func:`flag_fixed_n`)."""
FIXED_N_COLUMNS = ("95% interval", "sign-flip p")

RATIOS = frozenset({"rohe"})


def _signed(x: float, metric: str) -> str:
    return f"{x:+.4f}" if metric in RATIOS else f"{x:+.1f}"


def _e(x: float) -> str:
    return f"{x:.3g}"


def _settled(pair: dict[str, Any], reference: str) -> str:
    k = pair.get("settled_after")
    if k is None:
        return "-"
    side = "above" if pair.get("direction", 0) > 0 else "below"
    return f"after {k} trial{'s' if k != 1 else ''} (t{k - 1}): {side} {reference}"


def _status(pair: dict[str, Any], max_trials: int) -> str:
    status = str(pair.get("status", ""))
    if status == "cannot be settled":
        best = pair.get("best_reachable")
        reach = "" if best is None else f": at most {_e(best)} reachable"
        return f"cannot be settled within {max_trials} trials{reach}"
    return status


def sequential_table(rec: dict[str, Any], key: str = "sequential",
                     where: str = "") -> Table:
    """The table of one ``sequential.json`` (:func:`testbed.results.sequential.record`)."""
    ref, metric = str(rec["reference"]), str(rec["metric"])
    alpha, max_trials = float(rec["alpha"]), int(rec["max_trials"])
    done, minimum = int(rec["trials_done"]), int(rec["min_trials"])
    header = ["algorithm", f"per trial (minus {ref})", "e-value after each trial",
              "settled", "e-value now (max)", "anytime p (1 / max e)", "status",
              "trials saved"]
    rows: list[list[str]] = []
    csv_rows: list[list[Any]] = [["algorithm", "metric", "trials", "settled_after",
                                  "direction", "e_value", "e_max", "anytime_p", "status",
                                  "trials_saved",
                                  "e_values", "differences"]]
    for name, pair in rec["pairs"].items():
        diffs = [float(d) for d in pair["differences"]]
        es = [float(e) for e in pair["e_values"]]
        saved = max_trials - pair["settled_after"] if pair.get("settled_after") else None
        rows.append([
            name, ", ".join(f"t{k}: {_signed(d, metric)}" for k, d in enumerate(diffs)) or "-",
            ", ".join(f"t{k}: {_e(e)}" for k, e in enumerate(es)) or "-",
            _settled(pair, ref),
            f"{_e(es[-1])} ({_e(max(es))})" if es else "-",
            f"{anytime_p(es):.3g}" if es else "-", _status(pair, max_trials),
            "-" if saved is None else str(saved)])
        csv_rows.append([name, metric, len(diffs), pair.get("settled_after") or "",
                         pair.get("direction", 0), es[-1] if es else "",
                         max(es) if es else "", anytime_p(es) if es else "",
                         pair.get("status", ""),
                         "" if saved is None else saved,
                         " ".join(f"{e:.6g}" for e in es), " ".join(f"{d:.6g}" for d in diffs)])
    title = (f"Sequential test{where}: each algorithm against {ref} on {metric}, "
             f"settled at e-value >= {_e(1 / alpha)} (alpha {alpha:g})")
    return Table(key, title, header, rows, _notes(rec, done, minimum, max_trials), csv_rows)


def _notes(rec: dict[str, Any], done: int, minimum: int, max_trials: int) -> list[str]:
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
    return [
        decided,
        _fewest(float(rec["alpha"]), len(rec["pairs"])),
        "Anytime-valid, by betting (Waudby-Smith and Ramdas, \"Estimating means of "
        "bounded random variables by betting\", JRSS-B 2023; Shafer and Vovk's testing "
        "by betting): per pair, two wealths bet each trial on the sign of its "
        "difference, one that the algorithm is above the reference, one below, each "
        "difference divided by half the mean |difference| of the trials before it and "
        "clipped to [-1, 1] (the first: its sign); the e-value is their average. Under "
        "\"no difference\" (each difference's sign a fair coin, the sign-flip test's "
        "null) it is a nonnegative martingale, so by Ville's inequality it reaches "
        "1/alpha with probability at most alpha however often it is looked at: the "
        "protocol may stop on it, or be extended, and the answer holds. \"Cannot be "
        "settled\": one trial can at most multiply the e-value by "
        f"{1 + float(rec.get('cap', 0.9)):g}, and not even that on every trial left "
        "reaches 1/alpha. The bound is per pair; for all pairs at once use alpha / "
        "(pairs). Trials saved per pair: the fixed design's trials after the pair was "
        "settled.",
    ]


def _fewest(alpha: float, pairs: int) -> str:
    """The fewest trials the design can settle in, at alpha and (pairs sharing the
    reference) at the Bonferroni split alpha / pairs."""

    def at(a: float) -> str:
        n = fewest_trials(a)
        return (f"{n} trial{'s' if n != 1 else ''}" if n is not None
                else "more trials than the design allows")

    text = (f"The fewest trials this design can settle a pair in at alpha {alpha:g}: "
            f"{at(alpha)} (that many differences all of one sign, the most evidence a "
            f"trial can give, e-value >= {_e(1 / alpha)}).")
    if pairs > 1:
        text += (f" The {pairs} comparisons share the reference's runs: for all of them "
                 f"at once (a Bonferroni split, alpha / {pairs} = {alpha / pairs:.3g}, "
                 f"e-value >= {_e(pairs / alpha)}) it needs {at(alpha / pairs)}.")
    return text + (" Anytime p = min(1, 1 / the largest e-value so far): valid whenever "
                   "the protocol stopped, unlike a fixed-n p-value.")


def flag_fixed_n(table: Table) -> Table:
    """``table`` (a paired comparison) with its fixed-n columns marked and a note first:
    the sign-flip p-value and the t interval assume the number of trials was fixed in
    advance, and a protocol with ``until`` chose it from the data. Flagged, not
    dropped: the figures stay readable (and scripts keep their CSV), marked as what
    they are."""
    header = [f"{h} {FIXED_N_MARK}" if h in FIXED_N_COLUMNS else h for h in table.header]
    note = (f"{FIXED_N_MARK} fixed-n figures, not valid after optional stopping: this "
            "protocol ran with `until` and chose its number of trials from the data, so "
            "the sign-flip p-value and the 95% interval of the difference (both for a "
            "number of trials fixed in advance) overstate the evidence. Read the "
            "sequential table's e-value and anytime p instead.")
    return Table(table.key, table.title, header, table.rows, [note, *table.notes],
                 table.csv_rows, table.files)


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
    comparison (the paired table, else the intervals, else at the end), and the paired
    tables' fixed-n figures flagged (:func:`flag_fixed_n`)."""
    extra = sequential_tables(dirs)
    if not extra:
        return tables
    tables = [flag_fixed_n(t) if t.key.endswith("-paired") else t for t in tables]
    keys = [t.key for t in tables]
    for anchor in ("learning-paired", "learning-intervals"):
        if anchor in keys:
            at = keys.index(anchor) + 1
            return [*tables[:at], *extra, *tables[at:]]
    return [*tables, *extra]
