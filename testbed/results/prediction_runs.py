"""A run's signals scored as failure predictors (issue 36, item 1): the run's policy
pushes, each signal's figures on them, and what could not be scored and why.

Why from the records alone: a run's rows keep, per arm and step, the signals the learner
gave (``uncertainty`` and ``risk``; ``monitor`` for novelty, goal risk and the monitor's
own scores), and its data store settles each push's episode (``run_classes``), so any
finished run, old or new, is scored the same way, by ``testbed report`` and by scripts.
A signal a run did not compute (a critic its algorithm does not read gives zeros; rows
written before ``monitor`` existed keep uncertainty and risk only) is left out with the
reason, never scored as a constant.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from testbed.core.types import EpisodeOutcome, Mode
from testbed.fleet.algorithms import ALGORITHMS
from testbed.fleet.monitor_priority import both_high
from testbed.monitor.conformal import Replay, replay_online
from testbed.monitor.failure_head import FailureHead, design
from testbed.monitor.labels import POLICY_CLASSES, PolicyPushes, episode_ids, policy_pushes
from testbed.monitor.monitor_config import MonitorConfig
from testbed.monitor.predictor_metrics import LeadTime, auroc, average_precision, lead_time
from testbed.records.run_classes import STORE, run_classes
from testbed.records.steps import RecordError, read_steps
from testbed.records.store import MODES, RunDataError
from testbed.results.prediction_features import push_features, theta0_digest

__all__ = ["HEAD_INPUTS", "HEAD_K", "NEW_SIGNALS", "SIGNALS", "SPLITS", "RunPrediction",
           "SignalFigures", "add_failure_head", "head_groups", "replays", "run_prediction",
           "score_signal", "trial_seed"]

SIGNALS: Final = ("uncertainty", "risk", "novelty", "goal_risk")
"""Today's signals (issue 36's baseline), in the tables' order."""
NEW_SIGNALS: Final = ("ood", "ood_u", "fail_head")
"""The monitor's (item 3): the distance to the training data in the policy's feature
space, it together with the uncertainty (``both_high``), and the failure head
(``add_failure_head``: a violation within ``HEAD_K`` steps from theta_0's trunk features
and risk, learned on the runs from other theta_0)."""
NOT_SCORES: Final = frozenset({"alarm_threshold", "alarm_level"})
"""``monitor`` entries that are not a score of the arm (the alarm's threshold and level)."""
TOUCHING_MODES: Final = (MODES.index(Mode.TELEOP.value), MODES.index(Mode.RESET.value))
"""Modes in which a person has the arm: the episode is touched (it does not calibrate)."""
HEAD_K: Final = 3
"""The horizon the failure head learns (the issue's goal: a violation within 3 steps)."""
HEAD_INPUTS: Final = ("risk",)
"""The signals the failure head reads with the features, where a run has them: the
safety critic's risk. On the twin's baseline (15 runs pooled, AUROC at k = 3 of
C.U.R.'s and the monitor's runs) features with risk scored 0.94 / 0.93, with every signal
0.94 / 0.92, alone 0.93 / 0.89 (docs/notes/monitor.md): measured leave one trial seed
out, as every run shared theta_0's weights (issue 45, item 1), not re-measured yet.
Fixed here, not chosen by the code: a person chose risk from those three sets' scores
on the very folds they were scored on, so their 0.94 is the best of three there, with
the optimism that brings; the per-trial re-measure (protocols/twin-monitor-per-trial.toml)
scores this fixed set on runs the choice never saw, and no fold chooses an input."""
_READ_AS: Final = {"risk": "risk", "goal_risk": "goal_risk"}
_FROM_FRAMES: Final = ("uncertainty", "risk")


@dataclass(frozen=True)
class SignalFigures:
    """One signal on one run's policy pushes: per k (1..horizon) AUROC, average
    precision and the base rate of "a violation within k steps"; the same for "this
    episode fails"; the lead time and false alarms at the config's recall."""

    auroc_k: tuple[float, ...]
    ap_k: tuple[float, ...]
    base_k: tuple[float, ...]
    auroc_fail: float
    ap_fail: float
    base_fail: float
    lead: LeadTime
    pushes: int


@dataclass
class RunPrediction:
    """A run's policy pushes (None: unreadable), the figures of each signal it
    computed, the signals it did not (name -> why) and notes."""

    path: Path
    group: str
    pushes: PolicyPushes | None
    figures: dict[str, SignalFigures] = field(default_factory=dict)
    absent: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    frames: np.ndarray | None = None
    """The data-store index of each policy push (None: the classes came from the rows)."""
    touched: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """The episodes (``PolicyPushes.episode`` ids) in which a person had the arm (teleop
    or reset)."""

    def success_peaks(self, signal: str, touched: bool = False) -> np.ndarray:
        """The signal's peak per successful episode no person touched (``touched``: per
        one a person did), in the order they ran."""
        if self.pushes is None or signal not in self.figures:
            return np.zeros(0)
        ids, peaks = self.pushes.episode_max(signal, EpisodeOutcome.SUCCESS)
        return peaks[np.isin(ids, self.touched) == touched]


def _config(path: Path) -> dict[str, Any]:
    try:
        return tomllib.loads((path / "config.toml").read_text())
    except (OSError, tomllib.TOMLDecodeError):
        return {}


def _algorithm(path: Path) -> str | None:
    """The algorithm that ran (run.json's options: a trial's ``--algorithm`` is not in
    its config.toml), None when run.json cannot say."""
    try:
        meta = json.loads((path / "run.json").read_text())
    except (OSError, ValueError):
        return None
    name = meta.get("options", {}).get("algorithm") if isinstance(meta, dict) else None
    return str(name) if name else None


def _monitor_scores(rows: Sequence[dict[str, Any]], robots: Sequence[str], steps: int,
                    t0: int) -> dict[str, np.ndarray]:
    """The rows' ``monitor`` values as per-frame arrays (step-major; NaN: absent)."""
    index = {r: i for i, r in enumerate(robots)}
    n = len(robots)
    out: dict[str, np.ndarray] = {}
    for row in rows:
        s = int(row["t"]) - t0
        if not 0 <= s < steps:
            continue
        for entry in row["robots"]:
            for name, value in (entry.get("monitor") or {}).items():
                if name in NOT_SCORES:
                    continue
                arr = out.setdefault(name, np.full(steps * n, np.nan))
                arr[s * n + index[entry["robot"]]] = float(value)
    return out


def run_prediction(path: Path, group: str, config: MonitorConfig | None = None
                   ) -> RunPrediction:
    """Score every signal ``path``'s records hold, with ``config`` (default: the run's own
    ``[monitor]``, else the defaults)."""
    raw = _config(path)
    cfg = config or MonitorConfig.for_scoring(raw.get("monitor", {}))
    result = RunPrediction(path, group, None)
    try:
        rc = run_classes(path)
        rows = read_steps(path / "steps.jsonl", validate=False)
    except (RunDataError, RecordError, OSError, ValueError, KeyError) as exc:
        result.notes.append(f"its records could not be read: {exc}")
        return result
    result.notes += list(rc.notes)
    n = max(len(rc.robots), 1)
    steps = len(rc.frames) // n
    t0 = int(rc.frames["t"][0]) if len(rc.frames) else 0
    scores: dict[str, np.ndarray] = {k: rc.frames[k].astype(np.float64) for k in _FROM_FRAMES}
    scores |= _monitor_scores(rows, rc.robots, steps, t0)
    algorithm = _algorithm(path) or str(raw.get("algorithm", {}).get("name", ""))
    spec = ALGORITHMS.get(algorithm)
    reads = spec.reads if spec is not None else frozenset(SIGNALS)
    for name in SIGNALS:
        if name in _READ_AS and name not in reads:
            scores.pop(name, None)
            result.absent[name] = (f"its critic did not run ({algorithm or 'this run'} reads "
                                   f"no {name.replace('_', ' ')})")
        elif name not in scores:
            result.absent[name] = (
                "not in its rows" if any("monitor" in e for row in rows for e in row["robots"])
                else "not in the records (rows written before issue 36 keep uncertainty and "
                     "risk only)")
    pushes = policy_pushes(rc.frames, rc.classes.classes, rc.classes.outcomes,
                           rc.classes.episodes, scores)
    if rc.source == STORE:
        result.frames = np.flatnonzero(np.isin(rc.classes.classes, POLICY_CLASSES))
    if "ood" in pushes.scores and "uncertainty" in pushes.scores:
        pushes.scores["ood_u"] = _ood_u(pushes.scores["ood"], pushes.scores["uncertainty"])
        scores["ood_u"] = pushes.scores["ood_u"]
    result.pushes = pushes
    episode = episode_ids(rc.frames, rc.classes.episodes)
    result.touched = np.unique(episode[np.isin(rc.frames["mode"], TOUCHING_MODES)])
    for name in scores:
        values = pushes.scores[name]
        if np.isnan(values).all():
            result.absent[name] = "no policy push has it"
            continue
        if np.all(values[~np.isnan(values)] == 0.0):
            result.absent[name] = "0 on every policy push (not computed: for ood, a policy " \
                                  "whose features were never kept)"
            continue
        result.figures[name] = score_signal(pushes, name, cfg)
    return result


def _ood_u(ood: np.ndarray, uncertainty: np.ndarray) -> np.ndarray:
    """``ood_u`` of each push, each part over its median among the run's policy pushes
    (NaN where either part is)."""
    out = np.full(ood.shape, np.nan)
    ok = ~np.isnan(ood) & ~np.isnan(uncertainty)
    if ok.any():
        out[ok] = both_high([ood[ok], uncertainty[ok]], [ood[ok], uncertainty[ok]])
    return out


def _safe(f: Any, s: np.ndarray, y: np.ndarray) -> float:
    return float(f(s, y)) if s.size else math.nan


def score_signal(p: PolicyPushes, name: str, cfg: MonitorConfig) -> SignalFigures:
    """The figures of signal ``name`` on ``p`` (pushes without a value left out)."""
    has = ~np.isnan(p.scores[name])
    s = p.scores[name]
    au, ap, base = [], [], []
    for k in range(1, cfg.horizon + 1):
        label, known = p.within(k)
        use = has & known
        au.append(_safe(auroc, s[use], label[use]))
        ap.append(_safe(average_precision, s[use], label[use]))
        base.append(float(label[use].mean()) if use.any() else math.nan)
    settled = has & (p.fails | p.succeeded)
    fail = p.fails[settled]
    lead = lead_time(s[has], p.episode[has], p.to_violation[has], p.fails[has],
                     p.succeeded[has], cfg.recall)
    return SignalFigures(tuple(au), tuple(ap), tuple(base),
                         _safe(auroc, s[settled], fail), _safe(average_precision, s[settled], fail),
                         float(fail.mean()) if fail.size else math.nan, lead, int(has.sum()))


def add_failure_head(runs: Sequence[RunPrediction], cfg: MonitorConfig
                     ) -> tuple[str | None, FailureHead | None]:
    """Score each run with a failure head on its pushes' trunk features under theta_0
    and its signals (``HEAD_INPUTS`` it has), fitted on the runs of the other groups
    (``head_groups``: leave one theta_0 out, theta_0 identified by a hash of its policy's
    weights, where the runs have two or more, so no run is scored by a head that saw its
    policy; else leave one trial seed out, which holds out no policy), as the signal
    ``fail_head``. Runs of every algorithm are pooled: the labels are the policy's own
    pushes, whoever allocated the people.

    The inputs are fixed (``HEAD_INPUTS``, and the features), never chosen by comparing
    scores on these folds: a run's head reads what its training runs have of them, which
    depends on which signals the runs computed, not on any label (issue 45, item 1).

    Returns (why no run could be scored, or None; the head fitted on every usable run
    that has ``HEAD_INPUTS``, on the features alone when none has, for ``[monitor]
    head``, its ``fitted_on`` naming the split, the theta_0 digests and the trial seeds
    it saw; None if none could be)."""
    usable: list[tuple[RunPrediction, str, np.ndarray]] = []
    for r in runs:
        if r.pushes is None:
            continue
        why = _features(r)
        if isinstance(why, str):
            r.absent.setdefault("fail_head", why)
        else:
            usable.append((r, *why))
    split, group = head_groups([(r.path, d) for r, d, _ in usable])
    if split is None:
        return ("the failure head needs runs from two theta_0 with features (or, from "
                "one theta_0, two trial seeds)"), None
    for r, _, feats in usable:
        inputs = [s for s in HEAD_INPUTS if s in r.figures]
        pool = [(o, f) for o, _, f in usable if group[o.path] != group[r.path]
                and all(s in o.figures for s in inputs)]
        try:
            head = _fit(pool, inputs)
        except ValueError as exc:
            r.absent.setdefault("fail_head", f"its head could not be fitted: {exc}")
            continue
        assert r.pushes is not None
        r.pushes.scores["fail_head"] = _predict(head, r.pushes, feats)
        r.figures["fail_head"] = score_signal(r.pushes, "fail_head", cfg)
    pool = [(r, d, f) for r, d, f in usable if all(s in r.figures for s in HEAD_INPUTS)]
    inputs: list[str] = list(HEAD_INPUTS) if pool else []  # else features alone
    pool = pool or usable
    try:
        final = _fit([(r, f) for r, _, f in pool], inputs)
    except ValueError:
        return None, None
    final.fitted_on["theta_0"] = len({d for _, d, _ in pool})
    final.fitted_on["theta0_digests"] = sorted({d for _, d, _ in pool})
    final.fitted_on["trial_seeds"] = sorted({s for r, _, _ in pool
                                             if (s := trial_seed(r.path)) is not None})
    final.fitted_on["split"] = split
    return None, final


SPLITS: Final = ("theta_0", "trial seed")
"""What ``head_groups`` leaves out: a theta_0 (a policy the head never saw), or, when
every run shares one theta_0, a trial seed (the same policy, other episodes)."""


def trial_seed(run: Path) -> int | None:
    """The run's trial seed (run.json's options), None when run.json cannot say."""
    try:
        meta = json.loads((run / "run.json").read_text())
        seed = meta["options"]["seed"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return int(seed) if isinstance(seed, int) else None


def head_groups(runs: Sequence[tuple[Path, str]]) -> tuple[str | None, dict[Path, str]]:
    """How the failure head's runs (folder, theta_0 digest) are grouped for scoring:
    by theta_0 when they have two or more (``"theta_0"``); when they all share one, by
    trial seed (``"trial seed"``), named so, since no policy is then held out; None
    (and no groups) when neither gives two groups (or a run's seed is unknown)."""
    if len({d for _, d in runs}) >= 2:
        return SPLITS[0], {p: d for p, d in runs}
    seeds = {p: trial_seed(p) for p, _ in runs}
    if None in seeds.values() or len(set(seeds.values())) < 2:
        return None, {}
    return SPLITS[1], {p: f"seed {s}" for p, s in seeds.items()}


def _features(r: RunPrediction) -> tuple[str, np.ndarray] | str:
    if r.frames is None:
        return "its classes came from its rows: no images to read"
    digest = theta0_digest(r.path)
    if digest is None:
        return "it kept no theta_0 (learner-start.pt)"
    feats = push_features(r.path, r.frames, digest)
    return feats if isinstance(feats, str) else (digest, feats)


def _rows(p: PolicyPushes, feats: np.ndarray, inputs: Sequence[str]
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = design(p.scores, inputs, feats)
    label, known = p.within(HEAD_K)
    return x, label, known & ~np.isnan(x).any(axis=1)


def _fit(pool: Sequence[tuple[RunPrediction, np.ndarray]], inputs: Sequence[str]
         ) -> FailureHead:
    if not pool:
        raise ValueError("no run of another group (theta_0, or trial seed) has its signals")
    parts = []
    for r, feats in pool:
        assert r.pushes is not None
        parts.append(_rows(r.pushes, feats, inputs))
    x = np.concatenate([x[ok] for x, _, ok in parts])
    y = np.concatenate([y[ok] for _, y, ok in parts])
    head = FailureHead.fit(x, y, inputs, features=pool[0][1].shape[1], k=HEAD_K)
    head.fitted_on["runs"] = [str(r.path.name) for r, _ in pool]
    return head


def _predict(head: FailureHead, p: PolicyPushes, feats: np.ndarray) -> np.ndarray:
    x = design(p.scores, head.inputs, feats)
    out = np.full(len(p), np.nan)
    has = ~np.isnan(x).any(axis=1)
    out[has] = head.predict(x[has])
    return out


def replays(runs: Sequence[RunPrediction], signal: str, cfg: MonitorConfig
            ) -> tuple[Replay, Replay]:
    """The split and the ACI alarm replayed on ``signal`` over ``runs`` (one algorithm's
    trials), as deployed: each run's untouched successful episodes in the order they ran,
    each judged by the alarm as it stood before it (``replay_online``: ``monitor.window``,
    ``monitor.alpha``, ``monitor.gamma``), the rate pooled over runs with its upper bound
    clustered by run. A run whose pushes could not be read gives no episode."""
    peaks = [r.success_peaks(signal) for r in runs]
    return (replay_online(peaks, cfg.alpha, cfg.window, kind="split"),
            replay_online(peaks, cfg.alpha, cfg.window, kind="aci", gamma=cfg.gamma))
