"""A run's signals scored from its records (issue 36, item 1): a planted oracle signal
ranks perfectly at its own horizon, a constant one at chance, a signal the run did not
compute is named with the reason, and the report carries the tables."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from testbed.monitor.failure_head import FailureHead
from testbed.monitor.monitor_config import MonitorConfig
from testbed.records.run_dir import START_LEARNER
from testbed.records.step_record import StepRecord
from testbed.records.steps import RunWriter
from testbed.records.store import RunDataWriter
from testbed.results.prediction_features import theta0_digest
from testbed.results.prediction_runs import run_prediction
from testbed.results.report_prediction import prediction_tables
from tests.testbed.test_frame_classes_records import auto, frames_of, step

ROBOTS = ["c/left", "c/right"]
G = [(0.2, 0.3), (0.7, 0.6), (0.4, 0.8), (0.5, 0.5)]
LAST_BIAS = "members.0.1.4.bias"
"""The policy's output bias (after the trunk): moving it changes the weights, not the
trunk's features."""


def plan(rng: np.random.Generator, steps: int, fail_share: float = 0.4
         ) -> list[dict[str, Any]]:
    """One arm: policy episodes that succeed or end in a violation (a share
    ``fail_share`` of them), then a reset."""
    out: list[dict[str, Any]] = []
    g = 0
    while len(out) < steps:
        goal = G[g % len(G)]
        n = int(rng.integers(2, 7))
        fail = rng.random() < fail_share
        out += [auto(goal=goal) for _ in range(n - 1)]
        if fail:
            out += [auto(goal=goal, violation=True), step("idle", goal=goal),
                    step("reset", 0, goal=goal)]
        else:
            out.append(auto(goal=goal, success=True))
        g += 1
    return out[:steps]


def _violation_ahead(p: list[dict[str, Any]], t: int) -> int | None:
    """Steps from ``t`` to a violation of the same episode at most 2 steps ahead."""
    for d in range(3):
        if t + d >= len(p) or p[t + d]["success"]:
            return None
        if p[t + d]["violation"]:
            return d
    return None


def theta0(run: Path, kept_as: int, weights: int | None = None, critics: int = 0) -> None:
    """A theta_0 for ``run``: one small policy saved with ``kept_as`` for its seed (and a
    sampler state of its own). Its weights are ``weights``' (default ``kept_as``): the
    same trunk every time, so the features mean the same, with the policy's last bias
    moved by ``weights`` / 100, so another ``weights`` is another network (the digest
    hashes the weights, not the file); ``critics`` moves every critic parameter (net
    and target) by ``critics`` / 100: what BC and C.U.R. pretraining differ by."""
    import torch

    from testbed.learning import checkpoint
    from testbed.learning.learner import Learner
    from testbed.learning.learning_config import LearningConfig

    state = Learner(LearningConfig(ensemble_size=1), seed=0).state_dict()
    w = kept_as if weights is None else weights
    state["policy"][LAST_BIAS] = state["policy"][LAST_BIAS] + w / 100
    for critic in ("safety", "goal"):
        for part in ("net", "target"):
            state[critic][part] = {k: v + critics / 100 if v.is_floating_point() else v
                                   for k, v in state[critic][part].items()}
    state["sampler"] = torch.Generator().manual_seed(kept_as).get_state()
    checkpoint.save_atomic({**state, "seed": kept_as}, run / START_LEARNER)


def write_run(run: Path, algorithm: str, seed: int, steps: int = 240,
              theta: int | None = None, fail_share: float = 0.4,
              weights: int | None = None, trial: int | None = None) -> None:
    """Rows with an ``oracle`` monitor score (1 when the episode's violation is at most
    2 steps ahead), a constant one, one that is always 0 (never computed), and the data
    store; with ``theta``, the images show what the oracle knows (bright when a violation
    is at most 2 steps ahead) and the run keeps a theta_0 (``theta0``: seed ``theta``,
    weights ``weights``, default ``theta``'s); ``trial``: the trial seed run.json keeps
    (None: run.json says none)."""
    rng = np.random.default_rng(seed)
    plans = (plan(rng, steps, fail_share), plan(rng, steps, fail_share))
    frames = frames_of(*plans)
    run.mkdir(parents=True)
    data = RunDataWriter(run, ROBOTS)
    with RunWriter(run) as w:
        for t in range(steps):
            row: dict[str, Any] = {"t": t, "robots": [], "wall_time": 1.7e9 + t,
                                   "duration_s": 1.0}
            for a, p in enumerate(plans):
                ahead = _violation_ahead(p, t)
                row["robots"].append({
                    "robot": ROBOTS[a], "mode": p[t]["mode"], "human": p[t]["human"],
                    "action": p[t]["action"], "success": p[t]["success"],
                    "violation": p[t]["violation"], "uncertainty": float(rng.random()),
                    "risk": float(rng.random()) / 2, "key": [0.0],
                    "monitor": {"oracle": 1.0 if ahead is not None else 0.0, "flat": 0.5,
                                "dead": 0.0}})
            f = frames[t * 2:(t + 1) * 2]
            images = np.zeros((2, 64, 64, 3), np.uint8)
            if theta is not None:
                for a, entry in enumerate(row["robots"]):
                    level = 200 if entry["monitor"]["oracle"] else 40
                    images[a] = rng.integers(level - 30, level + 30, (64, 64, 3))
            data.append(StepRecord.from_row(row, 0, images, f["observed"],
                                            f["goal"]).to_frames())
            w.write_step(row)
    data.close()
    options: dict[str, Any] = {"algorithm": algorithm}
    if trial is not None:
        options["seed"] = trial
    (run / "run.json").write_text(json.dumps({"options": options}))
    if theta is not None:
        theta0(run, theta, weights)


def test_an_oracle_ranks_perfectly_at_its_horizon_and_a_constant_at_chance(
        tmp_path: Path) -> None:
    write_run(tmp_path / "a", "fleet-ed", 0)
    r = run_prediction(tmp_path / "a", "fleet-ed")
    oracle, flat = r.figures["oracle"], r.figures["flat"]
    assert oracle.auroc_k[2] == 1.0 and oracle.ap_k[2] == 1.0  # k = 3: its own horizon
    assert oracle.auroc_k[0] < 1.0 and oracle.auroc_k[4] < 1.0
    assert flat.auroc_k == (0.5,) * 5 and flat.auroc_fail == 0.5
    assert flat.ap_k[2] == pytest.approx(flat.base_k[2])
    assert 0.0 < oracle.base_k[0] < oracle.base_k[2] < oracle.base_k[4] < 1.0
    # every failed episode has its violation within 3 of its last pushes: caught, lead 0-2
    assert oracle.lead.caught == 1.0 and set(oracle.lead.steps) <= {0, 1, 2}
    assert oracle.lead.false_alarms_per_success == 0.0
    assert "uncertainty" in r.figures
    assert r.absent == {"risk": "its critic did not run (fleet-ed reads no risk)",
                        "goal_risk": "its critic did not run (fleet-ed reads no goal risk)",
                        "novelty": "not in its rows",
                        "dead": "0 on every policy push (not computed: for ood, a policy "
                                "whose features were never kept)"}


def test_the_report_tables_say_each_signal_per_algorithm_with_intervals(tmp_path: Path) -> None:
    for s in range(3):  # runs 0 and 1 from one theta_0, run 2 from another
        write_run(tmp_path / f"cur-t{s}", "cur", s, theta=s // 2)
    tables = {t.key: t for t in prediction_tables(
        {"cur": [tmp_path / f"cur-t{s}" for s in range(3)]}, MonitorConfig(horizon=3))}
    auc = tables["prediction-auroc"]
    assert auc.header[4:] == ["k=1", "k=2", "k=3", "episode fails"]
    oracle = next(r for r in auc.rows if r[1] == "oracle")
    # three runs of AUROC 1: the betting interval's lower end is the m where three full
    # bets against it reach 1 / alpha, (1 + 0.9 (1 - m) / m)^3 = 40, m = 0.271
    assert oracle[2] == "3" and oracle[6] == "1.000 [0.271, 1.000] (n=3)"
    signals = [r[1] for r in auc.rows]
    # risk: cur reads it (noise here); the failure head, fitted on the runs from the other
    # theta_0, reads in the images what the oracle knows: as good as the oracle at k = 3
    assert signals == ["uncertainty", "risk", "fail_head", "flat", "oracle"]
    head = next(r for r in auc.rows if r[1] == "fail_head")
    risk = next(r for r in auc.rows if r[1] == "risk")
    assert float(head[6].split()[0]) > 0.97 and float(risk[6].split()[0]) < 0.7
    kept = auc.files["failure-head.json"]  # the head on all three, for [monitor] head
    (tmp_path / "head.json").write_bytes(kept)
    fitted = FailureHead.load(tmp_path / "head.json")
    assert (fitted.inputs, fitted.features, fitted.k) == (("risk",), 64, 3)
    assert fitted.fitted_on["theta_0"] == 2 and len(fitted.fitted_on["runs"]) == 3
    digests = sorted({theta0_digest(tmp_path / f"cur-t{s}") for s in range(3)})
    assert fitted.fitted_on["split"] == "theta_0" and len(digests) == 2
    assert fitted.fitted_on["theta0_digests"] == digests  # what the report checks it by
    assert "fail_head: scored leave one theta_0 out (2 theta_0" in " ".join(auc.notes)
    assert (tmp_path / "cur-t0" / "monitor-features.npz").is_file()  # computed once
    assert "(base rate)" in [r[1] for r in tables["prediction-ap"].rows]
    rel = tables["prediction-reliability"]
    assert {r[1] for r in rel.rows} == {"risk", "fail_head"}
    # the head (each run scored by one that never saw its theta_0) is judged against
    # what it predicts, a violation within 3 steps: near 0 where it says 0, 1 where 1
    head_bins = [(r[2], r[5]) for r in rel.rows if r[1] == "fail_head"]
    assert head_bins == [("[0.0, 0.1)", "0.000"), ("[0.9, 1.0)", "1.000")], head_bins
    assert "cur, fail_head: expected calibration error 0.00" in " ".join(rel.notes)
    risk_bins = [r[2] for r in rel.rows if r[1] == "risk"]  # random in [0, 0.5): five bins
    assert risk_bins == [f"[{b / 10:.1f}, {(b + 1) / 10:.1f})" for b in range(5)]
    alarm = {r[1]: r for r in tables["prediction-alarm"].rows}
    # the oracle is 0 on every push of a successful episode (no violation ahead), so every
    # calibration peak is 0 and no untouched successful episode scores above the
    # threshold: no false alarm, split or ACI (whose level rises by gamma alpha = 0.0025
    # an episode, short of 1, where it would fire on everything). Each run judges from its
    # 20th (19 calibrate first: 1 / alpha - 1). 0 alarms in 3 runs: the same rate in each
    # (design effect 1), Clopper-Pearson on judged (z / t_2)^2 effective episodes, which is
    # above alpha: 3 runs cannot show a rate below 0.05
    from scipy import stats

    successes = [successful_episodes(s) for s in range(3)]
    judged = sum(max(0, n - 19) for n in successes)
    n_eff = judged * (stats.norm.ppf(0.95) / stats.t.ppf(0.95, 2)) ** 2
    upper = 1 - 0.05 ** (1 / n_eff)
    most = 0.05 + (0.05 + 0.05 * 0.95) / (0.05 * min(n - 19 for n in successes))
    assert upper > 0.05
    assert alarm["oracle"][3:] == ["3", str(judged), f"0.000 [{upper:.3f}] (0)", "no",
                                   f"0.000 [{upper:.3f}] (0)", "no", f"{most:.3f}"]
    md = "\n".join(t.markdown() for t in tables.values())
    assert "novelty: not in its rows" in md


def successful_episodes(seed: int, steps: int = 240) -> int:
    """The successful episodes ``write_run`` plans for ``seed`` (both arms): its own draw."""
    rng = np.random.default_rng(seed)
    return sum(x["success"] for _ in range(2) for x in plan(rng, steps))


def test_a_cell_counts_only_the_runs_that_entered_it(tmp_path: Path) -> None:
    """A run without a violation has no positive: no AUROC or average precision of any
    signal for any target. It computed the signals (runs: 3), but each cell says 2."""
    for s in range(2):
        write_run(tmp_path / f"r{s}", "fleet-ed", s)
    write_run(tmp_path / "calm", "fleet-ed", 2, fail_share=0.0)
    tables = {t.key: t for t in prediction_tables(
        {"ed": [tmp_path / "r0", tmp_path / "r1", tmp_path / "calm"]}, MonitorConfig(horizon=3))}
    for key in ("prediction-auroc", "prediction-ap"):
        row = next(r for r in tables[key].rows if r[1] == "uncertainty")
        assert row[2] == "3" and all(c.endswith("(n=2)") for c in row[4:]), row
        csv = tables[key].csv_rows
        runs = [i for i, h in enumerate(csv[0]) if h.endswith("_runs")]
        line = next(r for r in csv[1:] if r[1] == "uncertainty")
        assert line[2] == 3 and len(runs) == 4 and all(line[i] == 2 for i in runs)
        for row in tables[key].rows:  # every interval inside [0, 1] (t over 2 runs is not)
            for c in row[4:]:
                low, high = map(float, c.split("[")[1].split("]")[0].split(", "))
                assert 0.0 <= low <= float(c.split()[0]) <= high <= 1.0, row


def test_the_failure_head_says_why_it_could_not_score_a_run(tmp_path: Path) -> None:
    """One theta_0 for every run: no run could be scored by a head that never saw its
    policy, and the table says so; a run without a theta_0 is named with its reason."""
    write_run(tmp_path / "a", "cur", 0, theta=0)
    write_run(tmp_path / "b", "cur", 1, theta=0)
    write_run(tmp_path / "c", "cur", 2)
    tables = {t.key: t for t in prediction_tables(
        {"cur": [tmp_path / n for n in "abc"]}, MonitorConfig(horizon=3))}
    auc = tables["prediction-auroc"]
    assert "fail_head" not in [r[1] for r in auc.rows] and not auc.files
    md = auc.markdown()
    assert ("fail_head: the failure head needs runs from two theta_0 with features (or, "
            "from one theta_0, two trial seeds)") in md
    assert "fail_head: it kept no theta_0 (learner-start.pt)" in md


def test_one_theta_0_is_its_weights_not_its_file(tmp_path: Path) -> None:
    """Two trials that start from one network save it with their own seed and sampler
    (issue 45, item 1): the files differ, the digest does not, and the report counts one
    theta_0, so no run can be scored by a head that never saw its policy. Other weights,
    with the same seed, are another theta_0."""
    write_run(tmp_path / "a", "cur", 0, theta=0)
    write_run(tmp_path / "b", "cur", 1, theta=1, weights=0)  # seed 1, weights of a
    theta0(tmp_path / "c", kept_as=0, weights=1)  # seed 0, other weights
    a, b = (tmp_path / n / START_LEARNER for n in "ab")
    assert a.read_bytes() != b.read_bytes()
    digest = {n: theta0_digest(tmp_path / n) for n in "abc"}
    assert digest["a"] == digest["b"] and digest["a"] != digest["c"]
    assert all(len(d or "") == 64 for d in digest.values()), digest
    assert theta0_digest(tmp_path / "none") is None
    tables = {t.key: t for t in prediction_tables(
        {"cur": [tmp_path / "a", tmp_path / "b"]}, MonitorConfig(horizon=3))}
    auc = tables["prediction-auroc"]
    assert "fail_head" not in [r[1] for r in auc.rows] and not auc.files
    assert "fail_head: the failure head needs runs from two theta_0 with features" in \
        auc.markdown()


def test_one_theta_0_is_split_by_trial_seed_and_says_no_policy_was_held_out(
        tmp_path: Path) -> None:
    """Every run from one theta_0 (a protocol without pretrain_per_trial), three trial
    seeds: each run is scored by a head fitted on the other seeds' runs, and the report
    names that split for what it is, never claiming a held-out policy (issue 45)."""
    for s in range(3):
        write_run(tmp_path / f"cur-t{s}", "cur", s, theta=s, weights=0, trial=s)
    tables = {t.key: t for t in prediction_tables(
        {"cur": [tmp_path / f"cur-t{s}" for s in range(3)]}, MonitorConfig(horizon=3))}
    auc = tables["prediction-auroc"]
    head = next(r for r in auc.rows if r[1] == "fail_head")
    assert head[2] == "3"  # every run scored, by heads of the other two seeds
    notes = " ".join(auc.notes)
    assert "scored leave one trial seed out, not leave one theta_0 out" in notes
    assert "no policy was held out" in notes
    assert "leave one theta_0 out (" not in notes and "head that saw its policy" not in notes
    (tmp_path / "head.json").write_bytes(auc.files["failure-head.json"])
    fitted = FailureHead.load(tmp_path / "head.json").fitted_on
    assert (fitted["split"], fitted["theta_0"], fitted["trial_seeds"]) == \
        ("trial seed", 1, [0, 1, 2])


def test_theta_0_is_the_policy_the_head_reads_not_the_critics(tmp_path: Path) -> None:
    """The digest hashes the policy and nothing else of the learner (issue 45, item 1):
    a BC run pretrains no critic and a C.U.R. run of the same trial the safety critic,
    over one policy, so critics that differ leave one theta_0 (dropping the policy from
    the hash, or adding the critics to it, fails here); a policy that differs in one
    parameter of its last layer is another theta_0 (hashing only part of the policy, or
    the critics alone, fails here)."""
    theta0(tmp_path / "bc", kept_as=0, weights=0, critics=0)
    theta0(tmp_path / "cur", kept_as=0, weights=0, critics=3)
    theta0(tmp_path / "other", kept_as=0, weights=1, critics=0)
    assert (tmp_path / "bc" / START_LEARNER).read_bytes() != \
        (tmp_path / "cur" / START_LEARNER).read_bytes()
    digest = {n: theta0_digest(tmp_path / n) for n in ("bc", "cur", "other")}
    assert digest["bc"] == digest["cur"], "critics that differ made two theta_0"
    assert digest["bc"] != digest["other"], "policies that differ made one theta_0"
