"""The report's failure-prediction tables (issue 36, item 1): each signal scored as a
predictor of an arm's failure, per algorithm, with intervals over runs.

What each table says (docs/notes/monitor.md has the definitions and the twin's figures):

* AUROC and average precision of each signal for "a violation within k steps" (k = 1..
  ``monitor.horizon``) and "this episode fails", on the policy's own pushes: the mean
  over the group's runs with its 95 % interval in [0, 1] (``intervals.rate_interval``:
  betting below 10 runs, a bootstrap clustered by run from 10) and the number of runs
  that entered it (a run with no positive or no negative for the target has no AUROC
  and is not counted);
* the lead time and false alarms at the threshold that catches ``monitor.recall`` of the
  failed episodes (each run its own threshold);
* the reliability of the scores that claim to be probabilities (risk, goal risk):
  pooled over a group's runs, against "this episode fails";
* the conformal alarms (split and ACI) replayed on each run's untouched successful
  episodes in order: the false-alarm rate with its upper bound clustered by run
  (``testbed.monitor.false_alarms``), against ``monitor.alpha``;
* beside them, ``failure-head.json``: the failure head fitted on every run with theta_0's
  features (``prediction_runs.add_failure_head``), what ``[monitor] head`` reads.

The numbers come from ``testbed.results.prediction_runs`` (records only).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from testbed.monitor.monitor_config import MonitorConfig
from testbed.monitor.predictor_metrics import reliability
from testbed.results.head_provenance import live_head_notes
from testbed.results.intervals import BOOTSTRAP_MIN_TRIALS, Interval, interval, rate_interval
from testbed.results.prediction_runs import (
    HEAD_K,
    NEW_SIGNALS,
    SIGNALS,
    RunPrediction,
    add_failure_head,
    replays,
    run_prediction,
)
from testbed.results.report_tables import Table

__all__ = ["HEAD_FILE", "monitor_config", "monitor_tables", "prediction_tables", "rate_note",
           "split_note"]

HEAD_FILE = "failure-head.json"
"""The failure head fitted on the report's runs, beside its CSVs (``[monitor] head``)."""

PROBABILITIES = ("risk", "goal_risk", "fail_head")
"""Signals that claim to be a probability of a violation (a reliability table each):
the critics' of their episode's violation, the failure head's of one within ``HEAD_K``
steps (what it was fitted to say, so what its bins are judged against)."""
CAVEAT = ("Labels: a policy push's episode and the steps to its violation "
          "(testbed/monitor/labels.py). A person who took an arm because a signal was high "
          "may have prevented the violation it foresaw, which the label then counts as a "
          "false alarm: runs where people intervene often understate every signal; "
          "evaluation runs (people for hard resets only) do not.")


def _cell(iv: Interval) -> str:
    """The mean, its interval and, as ``(n=...)``, the runs that entered it."""
    if iv.method == "none":
        return "-"
    if iv.method == "one":
        return f"{iv.mean:.3f} (n=1)"
    return f"{iv.mean:.3f} [{iv.low:.3f}, {iv.high:.3f}] (n={iv.n})"


def _iv(values: Sequence[float]) -> Interval:
    """A rate's interval over the runs that have it (NaN: the run could not give it)."""
    return rate_interval([v for v in values if not math.isnan(v)])


def _count_iv(values: Sequence[float]) -> Interval:
    """A count's interval (t or BCa over runs), never below 0: a count cannot be."""
    iv = interval([v for v in values if not math.isnan(v)])
    return Interval(iv.mean, iv.low if math.isnan(iv.low) else max(0.0, iv.low), iv.high,
                    iv.n, iv.method)


def _without_negatives(values: Sequence[float], base: Sequence[float]) -> list[float]:
    """Average precision is 1 on a run whose pushes are all positive, whatever the
    signal: such a run has no negative and enters no cell (NaN)."""
    return [math.nan if b >= 1.0 else v for v, b in zip(values, base, strict=True)]


def rate_note(counts: Sequence[int]) -> str:
    """What the prediction tables' intervals are, and which rule these run counts used."""
    used = sorted(set(counts))
    kinds = ", ".join(f"{n} run{'s' if n != 1 else ''}: " + (
        "no interval" if n < 2 else "cluster bootstrap" if n >= BOOTSTRAP_MIN_TRIALS
        else "betting") for n in used) or "no run"
    return (f"95% intervals of the mean over runs, in [0, 1]: below {BOOTSTRAP_MIN_TRIALS} "
            "runs (or all runs equal) the betting interval for a mean bounded in [0, 1] "
            "(Waudby-Smith and Ramdas 2023: valid at any number of independent runs, no "
            f"normality), from {BOOTSTRAP_MIN_TRIALS} on a percentile bootstrap "
            f"clustered by run (whole runs resampled, 9999 times, seeded); here {kinds}. "
            "(n=...): the runs that entered the cell; "
            "a run with no positive or no negative for its target is not counted. runs: "
            "the runs that computed the signal.")


def split_note(fitted_on: Mapping[str, Any]) -> str:
    """What the failure head's leave-one-out held out (``prediction_runs.head_groups``):
    a theta_0, a policy no run's head saw; or, with one theta_0 for every run, a trial
    seed, which holds out no policy, said so."""
    n = fitted_on.get("theta_0", 0)
    if fitted_on.get("split") == "trial seed":
        return ("scored leave one trial seed out, not leave one theta_0 out: every run "
                "started from one theta_0 (one policy's weights), so each run was scored "
                "by a head fitted on runs of the same policy, and no policy was held out "
                "(pretrain_per_trial = true in a protocol gives each trial its own).")
    return (f"scored leave one theta_0 out ({n} theta_0, identified by a hash of their "
            "policy's weights): no run was scored by a head that saw its policy.")


def _num(x: float) -> float | str:
    return "" if math.isnan(x) else round(float(x), 6)


def monitor_config(config: Mapping[str, Any]) -> MonitorConfig:
    """A run's ``[monitor]`` (its config.toml as a dict; the defaults for runs before it)."""
    return MonitorConfig.for_scoring(dict(config.get("monitor", {})))


def monitor_tables(groups: Sequence[tuple[str, Sequence[Path], Mapping[str, Any]]],
                   monitor_runs: Sequence[Path]) -> list[Table]:
    """The report's failure-prediction tables for its groups (name, run folders, the first
    run's config.toml: its ``[monitor]``), and the monitor algorithm's own table for its
    runs, if any."""
    from testbed.results.report_alarm import alarm_table, false_alarm_table

    tables = prediction_tables({g: paths for g, paths, _ in groups},
                               monitor_config(groups[0][2]) if groups else None)
    alarms = alarm_table(monitor_runs)
    live = false_alarm_table({g: [p for p in paths if p in monitor_runs]
                              for g, paths, _ in groups})
    return tables + [t for t in (alarms, live) if t is not None]


def prediction_tables(groups: Mapping[str, Sequence[Path]],
                      config: MonitorConfig | None = None) -> list[Table]:
    """The tables for runs grouped by algorithm (name -> run folders)."""
    scored = {g: [run_prediction(p, g, config) for p in paths] for g, paths in groups.items()}
    cfg = config or MonitorConfig()
    every = [r for runs in scored.values() for r in runs]
    why, head = add_failure_head(every, cfg)
    if why is not None and len(every) > 1:
        for r in every:
            r.absent.setdefault("fail_head", why)
    ranking = _ranking(scored, cfg, "auroc")
    if head is not None:
        ranking.files[HEAD_FILE] = (json.dumps(head.to_json(), indent=1) + "\n").encode()
        reads = ", ".join(head.inputs) or "no signal"
        ranking.notes.append(
            f"fail_head: {split_note(head.fitted_on)} Its inputs are fixed ({reads} and "
            f"the trunk features), not chosen on these folds. The head fitted on "
            f"{len(head.fitted_on.get('runs', ()))} runs ({reads} and {head.features} trunk "
            f"features) is in {HEAD_FILE}, for [monitor] head with score = \"fail_head\" "
            "on runs of other theta_0 (it records the ones it saw).")
    ranking.notes += live_head_notes([p for paths in groups.values() for p in paths])
    return [ranking, _ranking(scored, cfg, "ap"), _lead(scored, cfg),
            _reliability(scored), _alarm(scored, cfg)]


def _signals(runs: Sequence[RunPrediction]) -> list[str]:
    known = (*SIGNALS, *NEW_SIGNALS)
    return [s for s in known if any(s in r.figures for r in runs)] + sorted(
        {s for r in runs for s in r.figures} - set(known))


def _absent_notes(scored: Mapping[str, Sequence[RunPrediction]]) -> list[str]:
    notes = []
    for g, runs in scored.items():
        why = {f"{s}: {w}" for r in runs for s, w in r.absent.items()}
        why |= {f"{r.path.name}: {n}" for r in runs for n in r.notes}
        if why:
            notes.append(f"{g}: not scored: " + "; ".join(sorted(why)))
    return notes


def _ranking(scored: Mapping[str, Sequence[RunPrediction]], cfg: MonitorConfig,
             which: str) -> Table:
    ks = range(1, cfg.horizon + 1)
    header = ["algorithm", "signal", "runs", "pushes", *(f"k={k}" for k in ks),
              "episode fails"]
    csv_rows: list[list[Any]] = [["algorithm", "signal", "runs", "pushes"] + [
        f"{c}_{s}" for c in [*(f"k{k}" for k in ks), "fails"]
        for s in ("mean", "low", "high", "runs")]]
    rows: list[list[str]] = []
    counts: list[int] = []
    for g, runs in scored.items():
        for sig in _signals(runs):
            figs = [r.figures[sig] for r in runs if sig in r.figures]
            if which == "auroc":
                per_k = [[f.auroc_k[k - 1] for f in figs] for k in ks]
                fails = [f.auroc_fail for f in figs]
            else:
                per_k = [_without_negatives([f.ap_k[k - 1] for f in figs],
                                            [f.base_k[k - 1] for f in figs]) for k in ks]
                fails = _without_negatives([f.ap_fail for f in figs],
                                           [f.base_fail for f in figs])
            ivs = [_iv(v) for v in per_k] + [_iv(fails)]
            counts += [iv.n for iv in ivs]
            pushes = sum(f.pushes for f in figs)
            rows.append([g, sig, str(len(figs)), str(pushes), *map(_cell, ivs)])
            csv_rows.append([g, sig, len(figs), pushes,
                             *(x for iv in ivs for x in (*map(_num, (iv.mean, iv.low, iv.high)),
                                                         iv.n))])
        if which == "ap" and runs and any(r.figures for r in runs):
            figs = [next(iter(r.figures.values())) for r in runs if r.figures]
            base = [_iv([f.base_k[k - 1] for f in figs]) for k in ks]
            base.append(_iv([f.base_fail for f in figs]))
            rows.append([g, "(base rate)", str(len(figs)), "", *map(_cell, base)])
    name = "AUROC" if which == "auroc" else "Average precision"
    notes = [("0.5: no better than chance. " if which == "auroc" else
              "The base rate (the share of positives) is what a signal without skill gets. ")
             + CAVEAT, rate_note(counts), *_absent_notes(scored)]
    return Table(f"prediction-{which}",
                 f"Failure prediction, {name}: each signal on the policy's own pushes, for "
                 "'a violation within k steps' and 'this episode fails' (mean over runs "
                 "[95% interval] (n=runs in it))", header, rows, notes, csv_rows)


def _lead(scored: Mapping[str, Sequence[RunPrediction]], cfg: MonitorConfig) -> Table:
    header = ["algorithm", "signal", "failed episodes", "caught", "lead (steps, median)",
              "false alarms per successful episode", "successful episodes alarmed"]
    rows, csv_rows = [], [["algorithm", "signal", "failed", "caught", "lead_median",
                           "false_alarms_per_success", "successes_alarmed"]]
    for g, runs in scored.items():
        for sig in _signals(runs):
            leads = [r.figures[sig].lead for r in runs if sig in r.figures]
            failed = sum(ld.failed for ld in leads)
            caught = _iv([ld.caught for ld in leads])
            steps = [s for ld in leads for s in ld.steps]
            median = float(np.median(steps)) if steps else math.nan
            fa = _count_iv([ld.false_alarms_per_success for ld in leads])
            share = _iv([ld.successes_alarmed for ld in leads])
            rows.append([g, sig, str(failed), _cell(caught),
                         "-" if math.isnan(median) else f"{median:g}", _cell(fa), _cell(share)])
            csv_rows.append([g, sig, failed, _num(caught.mean), _num(median), _num(fa.mean),
                             _num(share.mean)])
    return Table("prediction-lead",
                 f"Lead time and false alarms at recall {cfg.recall:g}: each run's threshold "
                 f"is the largest that alarms on at least {cfg.recall:.0%} of its failed "
                 "episodes before their violation", header, rows,
                 ["lead: steps from the first alarm to the violation, over every caught "
                  "episode of the group (0: the alarm came on the push that took the cube "
                  "out, before it ran); false alarms: alarmed policy pushes in episodes that "
                  "succeeded, per such episode; caught, false alarms and the share: mean "
                  "over runs [95% interval] (n=runs in it: a run with no failed episode has "
                  "no caught share); caught and the share as in prediction-auroc, false "
                  "alarms (a count) by t below 10 runs, BCa bootstrap from 10, never below "
                  "0."], csv_rows)


def _reliability(scored: Mapping[str, Sequence[RunPrediction]]) -> Table:
    header = ["algorithm", "signal", "bin", "pushes", "mean score", "episodes failed",
              "95% interval"]
    rows, csv_rows = [], [["algorithm", "signal", "low", "high", "pushes", "mean_score",
                           "frequency", "freq_low", "freq_high"]]
    notes = []
    for g, runs in scored.items():
        for sig in PROBABILITIES:
            s, y = [], []
            for r in runs:
                if sig in r.figures and r.pushes is not None:
                    p = r.pushes
                    if sig == "fail_head":
                        label, known = p.within(HEAD_K)
                    else:
                        label, known = p.fails, p.fails | p.succeeded
                    use = ~np.isnan(p.scores[sig]) & known
                    s.append(p.scores[sig][use])
                    y.append(label[use])
            if not s or not np.concatenate(s).size:
                continue
            table, ece = reliability(np.clip(np.concatenate(s), 0.0, 1.0), np.concatenate(y))
            notes.append(f"{g}, {sig}: expected calibration error {ece:.3f}")
            for b in table:
                rows.append([g, sig, f"[{b.low:.1f}, {b.high:.1f})", str(b.count),
                             f"{b.mean_score:.3f}", f"{b.frequency:.3f}",
                             f"[{b.freq_low:.3f}, {b.freq_high:.3f}]"])
                csv_rows.append([g, sig, b.low, b.high, b.count, _num(b.mean_score),
                                 _num(b.frequency), _num(b.freq_low), _num(b.freq_high)])
    notes.append("Is a 0.3 a 30 % chance? Each bin's pushes (of episodes that succeeded or "
                 "failed, every run of the group pooled) against the share whose episode "
                 "ended in a violation (Wilson interval); for fail_head (each run scored by "
                 f"a head that never saw its theta_0), the share with a violation within "
                 f"{HEAD_K} steps, what the head predicts. The safety critic estimates a "
                 "discounted probability (gamma_safe), so it sits below the frequency when "
                 "violations come late.")
    return Table("prediction-reliability",
                 "Reliability of the scores that claim a probability of a violation",
                 header, rows, notes, csv_rows)


def _alarm(scored: Mapping[str, Sequence[RunPrediction]], cfg: MonitorConfig) -> Table:
    header = ["algorithm", "signal", "alpha", "runs", "episodes judged",
              "split: rate [upper bound]", "split: bound <= alpha",
              "ACI: rate [upper bound]", "ACI: bound <= alpha", "ACI's guarantee (most)"]
    rows, csv_rows = [], [["algorithm", "signal", "alpha", "runs", "episodes",
                           "split_fired", "split_rate", "split_upper", "aci_fired",
                           "aci_rate", "aci_upper", "aci_guarantee"]]
    for g, runs in scored.items():
        for sig in _signals(runs):
            split, aci = replays(runs, sig, cfg)
            most = max(aci.guarantee, default=math.nan)

            def cell(rep: Any) -> str:
                if rep.rate.runs == 0:
                    return "-"
                return f"{rep.rate.rate:.3f} [{rep.rate.upper:.3f}] ({rep.rate.fired})"
            rows.append([g, sig, f"{cfg.alpha:g}", split.rate.runs, split.rate.episodes,
                         cell(split), _yes(split), cell(aci), _yes(aci),
                         "-" if math.isnan(most) else f"{most:.3f}"])
            csv_rows.append([g, sig, cfg.alpha, split.rate.runs, split.rate.episodes,
                             split.rate.fired, _num(split.rate.rate), _num(split.rate.upper),
                             aci.rate.fired, _num(aci.rate.rate), _num(aci.rate.upper),
                             _num(most)])
    return Table("prediction-alarm",
                 f"The conformal alarms replayed: false alarms per untouched successful "
                 f"episode against alpha {cfg.alpha:g} (window {cfg.window}, ACI's gamma "
                 f"{cfg.gamma:g})", header, [[str(c) for c in r] for r in rows],
                 ["Each run's successful episodes that no person touched (no teleop, no "
                  "reset), in the order they ran; each judged by the alarm as it stood "
                  "before it (fired: its peak above the threshold), then calibrating it "
                  "(testbed/monitor/conformal.py::replay_online). Split: the "
                  "ceil((n+1)(1-alpha))-th smallest of the window's peaks; ACI: the same "
                  "at a level moved by gamma (alpha - fired) after each episode. Rate: "
                  "alarmed over judged, pooled over runs (alarmed count in parentheses); "
                  "[upper bound]: one-sided 95 %, Korn-Graubard clustered by run "
                  "(testbed/monitor/false_alarms.py). ACI's guarantee: the most its rate "
                  "can be in the run with the fewest episodes, alpha + (alpha + gamma "
                  "(1 - alpha)) / (gamma T), for any sequence of peaks. "
                  f"The alarm judges from the {math.ceil(1 / cfg.alpha - 1 - 1e-12)}th "
                  "untouched success on (until then it stays silent). A person who took "
                  "an arm leaves its episode out: the replay says nothing of the alarm on "
                  "the successes people rescued."], csv_rows)


def _yes(rep: Any) -> str:
    """Whether a replay's upper bound is at most alpha ("-": nothing judged)."""
    return "-" if rep.rate.runs == 0 else ("yes" if rep.holds else "no")
