"""The report's tables of the monitor algorithm at work (issue 36, item 4): per run of
``monitor``, when its alarm became ready, who its people went to and why, and the
threshold it ended with; and its realised live false-alarm rate (issue 45, item 2): per
successful episode no person touched, did the alarm fire, pooled over a group's runs
with a one-sided upper bound clustered by run, the touched successes apart.

Why from the rows: each arm's row keeps the alarm's score and, once ready, its threshold
(``monitor.alarm_score``, ``monitor.alarm_threshold``), and the key (c, a, s, u, r) says
why an arm was eligible; so the table needs nothing but steps.jsonl, like the rest of the
report.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from testbed.core.types import EpisodeOutcome
from testbed.monitor.conformal import aci_bounds
from testbed.monitor.false_alarms import alarm_rate
from testbed.monitor.labels import POLICY_CLASSES, episode_ids
from testbed.monitor.monitor_config import MonitorConfig
from testbed.records.run_classes import run_classes
from testbed.records.steps import RecordError, read_steps
from testbed.records.store import RunDataError
from testbed.results.prediction_runs import TOUCHING_MODES
from testbed.results.report_tables import Table

__all__ = ["LiveAlarm", "alarm_table", "false_alarm_table", "live_alarm"]

_NAMES = ("c", "a", "s", "u", "r")


def _why(key: Sequence[float]) -> str | None:
    """The key's first positive entry (the reason an arm was eligible), or None."""
    for name, v in zip(_NAMES, key, strict=False):
        if v != 0:
            return name if v > 0 else None
    return None


def _run_row(path: Path) -> list[Any] | None:
    try:
        rows = read_steps(path / "steps.jsonl", validate=False)
    except (OSError, RecordError):
        return None
    ready_at: int | None = None
    threshold = float("nan")
    started = {"c": 0, "a": 0, "u": 0, "r": 0}
    alarmed = 0
    for row in rows:
        for r in row["robots"]:
            mon = r.get("monitor") or {}
            if "alarm_level" in mon or "alarm_threshold" in mon:
                ready_at = int(row["t"]) if ready_at is None else ready_at
            if "alarm_threshold" in mon:
                threshold = float(mon["alarm_threshold"])
            why = _why(r.get("key", []))
            alarmed += why == "a"
            if r.get("served") == 0 and why in started:  # an intervention's first step
                started[why] += 1
    return [path.name, "-" if ready_at is None else str(ready_at), alarmed,
            started["c"], started["a"], started["u"] + started["r"],
            "-" if threshold != threshold else f"{threshold:.3f}"]


def alarm_table(paths: Sequence[Path]) -> Table | None:
    """One row per run of the monitor algorithm (None when there is none)."""
    rows = [r for p in paths if (r := _run_row(p)) is not None]
    if not rows:
        return None
    header = ["run", "alarm ready at step", "arm-steps alarmed", "resets started",
              "teleops on an alarm", "teleops by C.U.R.'s rule (before ready)",
              "last threshold"]
    return Table("monitor-alarm", "The monitor algorithm at work: when its alarm was ready, "
                 "whom its people went to and why", header,
                 [[str(c) for c in r] for r in rows],
                 ["Before the alarm has its successful episodes (1/alpha - 1) the monitor "
                  "runs as C.U.R. (u, r); from then on a person goes only where the alarm "
                  "fires (a) or to a reset (c). An intervention counts once, at its first "
                  "step, under the key entry that made its arm eligible "
                  "(testbed/fleet/monitor_priority.py)."],
                 [["run", "ready_at", "alarmed", "resets", "alarm_teleops", "cur_teleops",
                   "threshold"], *rows])


@dataclass(frozen=True)
class LiveAlarm:
    """One monitor run's successful episodes with a policy push that settled while its
    alarm was ready, untouched and touched apart: how many, how many the alarm fired in
    (at a policy push: the row's key a), and the run's alarm (config)."""

    judged: int
    fired: int
    touched: int
    touched_fired: int
    arms: int
    config: MonitorConfig

    @property
    def guarantee(self) -> float:
        """The most ACI lets the untouched rate be (NaN: a split alarm promises nothing
        without exchangeability)."""
        if self.config.alarm != "aci":
            return math.nan
        return aci_bounds(self.config.alpha, self.config.gamma, self.judged, self.arms)[1]


def live_alarm(path: Path) -> LiveAlarm | None:
    """``path``'s episodes as its alarm saw them, from its records (None: unreadable).
    The episodes are ``testbed.records.frame_classes``'s, as the live alarm's
    (``testbed/fleet/monitor_priority.py``); ready: the success's row has the alarm's
    level (or, before issue 45, its threshold)."""
    try:
        rc = run_classes(path)
        rows = read_steps(path / "steps.jsonl", validate=False)
    except (RunDataError, RecordError, OSError, ValueError, KeyError):
        return None
    try:
        raw = tomllib.loads((path / "config.toml").read_text())
    except (OSError, tomllib.TOMLDecodeError):
        raw = {}  # a run without its config.toml: the defaults
    cfg = MonitorConfig.for_scoring(raw.get("monitor", {}))
    n = max(len(rc.robots), 1)
    fr = rc.frames
    t0 = int(fr["t"][0]) if len(fr) else 0
    alarmed = np.zeros(len(fr), bool)
    ready = np.zeros(len(fr), bool)
    index = {r: i for i, r in enumerate(rc.robots)}
    for row in rows:
        s = int(row["t"]) - t0
        if not 0 <= s < len(fr) // n:
            continue
        is_ready = any("alarm_level" in (e.get("monitor") or {})
                       or "alarm_threshold" in (e.get("monitor") or {}) for e in row["robots"])
        for e in row["robots"]:
            i = s * n + index[e["robot"]]
            ready[i] = is_ready
            key = e.get("key") or []
            alarmed[i] = len(key) > 1 and float(key[1]) > 0
    episode = episode_ids(fr, rc.classes.episodes)
    push = np.isin(rc.classes.classes, POLICY_CLASSES)
    success = rc.classes.outcomes == int(EpisodeOutcome.SUCCESS)
    counts = np.zeros((2, 2), int)  # [touched][fired]
    for ep in np.unique(episode[success & push]).tolist():
        at = episode == ep
        end = np.flatnonzero(at & np.asarray(fr["success"], bool))
        if end.size == 0 or not ready[end[-1]]:
            continue
        touched = bool(np.isin(fr["mode"][at], TOUCHING_MODES).any())
        counts[int(touched), int(bool((alarmed & push & at).any()))] += 1
    return LiveAlarm(int(counts[0].sum()), int(counts[0, 1]), int(counts[1].sum()),
                     int(counts[1, 1]), n, cfg)


def false_alarm_table(groups: Mapping[str, Sequence[Path]]) -> Table | None:
    """Per group of monitor runs, the realised live false-alarm rate (None: no run)."""
    header = ["algorithm", "alarm", "alpha", "runs", "untouched successes judged",
              "alarmed: rate [upper bound]", "bound <= alpha", "ACI's guarantee (most)",
              "touched successes", "touched alarmed"]
    rows: list[list[Any]] = []
    csv_rows: list[list[Any]] = [["algorithm", "alarm", "alpha", "gamma", "runs", "judged",
                                  "fired", "rate", "upper", "guarantee", "touched",
                                  "touched_fired"]]
    for g, paths in groups.items():
        live = [a for p in paths if (a := live_alarm(p)) is not None]
        if not live:
            continue
        cfg = live[0].config
        rate = alarm_rate([a.fired for a in live], [a.judged for a in live], cfg.alpha)
        most = max((a.guarantee for a in live if a.judged), default=math.nan)
        touched = sum(a.touched for a in live)
        touched_fired = sum(a.touched_fired for a in live)
        kinds = "/".join(sorted({a.config.alarm for a in live}))
        rows.append([g, kinds, f"{cfg.alpha:g}", len(live), rate.episodes,
                     "-" if rate.runs == 0 else
                     f"{rate.rate:.3f} [{rate.upper:.3f}] ({rate.fired})",
                     "-" if rate.runs == 0 else ("yes" if rate.holds else "no"),
                     "-" if math.isnan(most) else f"{most:.3f}", touched,
                     "-" if not touched else f"{touched_fired / touched:.3f} ({touched_fired})"])
        csv_rows.append([g, kinds, cfg.alpha, cfg.gamma, len(live), rate.episodes, rate.fired,
                         rate.rate, rate.upper, most, touched, touched_fired])
    if not rows:
        return None
    return Table("monitor-false-alarms", "The monitor's alarm live: false alarms per "
                 "untouched successful episode, from the rows",
                 header, [[str(c) for c in r] for r in rows],
                 ["Per run, the successful episodes with a policy push that ended while "
                  "the alarm was ready (the success's row has alarm_level or "
                  "alarm_threshold); alarmed: the alarm fired (key a) at one of its "
                  "policy pushes. Untouched: no teleop or reset in it, what the alarm "
                  "calibrates on and ACI judges; touched (a person had the arm) apart, "
                  "with no claim: the person may have been what made it succeed. "
                  "[upper bound]: one-sided 95 %, Korn-Graubard clustered by run "
                  "(testbed/monitor/false_alarms.py). ACI's guarantee: the most the rate "
                  "of the run with the fewest judged episodes T can be, alpha + (alpha + "
                  "A gamma (1 - alpha)) / (gamma T) with A arms, whatever the scores did "
                  "(testbed/monitor/conformal.py); none for the split alarm."], csv_rows)
