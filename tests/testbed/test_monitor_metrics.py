"""Failure prediction's arithmetic (issue 36, items 1, 2 and 7): the labels of the
policy's pushes from hand-built records, the metrics on cases with known answers, and the
conformal alarm's false-alarm rate against alpha by replay."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from testbed.core.types import EpisodeOutcome
from testbed.monitor.conformal import (
    ConformalAlarm,
    conformal_threshold,
    episodes_needed,
    replay_online,
    replay_split,
)
from testbed.monitor.labels import policy_pushes
from testbed.monitor.predictor_metrics import auroc, average_precision, lead_time, reliability
from testbed.records.frame_classes import classify
from tests.testbed.test_frame_classes_records import auto, frames_of, step, teleop

G1, G2 = (0.2, 0.3), (0.7, 0.6)


# ------------------------------------------------------------------ metrics
def test_auroc_and_average_precision_match_their_definitions() -> None:
    s, y = [0.1, 0.4, 0.35, 0.8], [0, 0, 1, 1]
    assert auroc(s, y) == pytest.approx(0.75)  # 3 of the 4 (pos, neg) pairs in order
    assert average_precision(s, y) == pytest.approx((1 / 1 + 2 / 3) / 2)
    assert auroc([0.5, 0.5], [0, 1]) == 0.5  # a tie counts half
    assert average_precision([0.5, 0.5], [0, 1]) == 0.5  # one threshold: precision 1/2
    assert auroc([1.0, 2.0, 3.0], [1, 1, 1]) != auroc([1.0, 2.0, 3.0], [1, 1, 1])  # NaN
    assert math.isnan(average_precision([1.0, 2.0], [0, 0]))
    rng = np.random.default_rng(0)
    y = rng.random(4000) < 0.2
    assert auroc(rng.random(4000), y) == pytest.approx(0.5, abs=0.03)
    assert average_precision(rng.random(4000), y) == pytest.approx(0.2, abs=0.03)
    assert auroc(y + 0.0, y) == 1.0 and average_precision(y + 0.0, y) == 1.0
    with pytest.raises(ValueError, match="NaN"):
        auroc([np.nan, 1.0], [0, 1])


def test_a_calibrated_score_has_a_small_calibration_error_and_a_halved_one_does_not() -> None:
    rng = np.random.default_rng(1)
    p = rng.random(20000)
    y = rng.random(20000) < p
    table, ece = reliability(p, y)
    assert ece < 0.02 and len(table) == 10
    assert sum(b.count for b in table) == 20000
    assert all(b.freq_low <= b.mean_score <= b.freq_high for b in table[1:-1])
    _, ece_bad = reliability(p, rng.random(20000) < p / 2)
    assert ece_bad > 0.2
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        reliability([1.5], [True])


def test_lead_time_is_the_first_alarm_before_each_caught_violation() -> None:
    # three failed episodes (ids 0-2) and two successful ones (3, 4), pushes in order
    episode = np.array([0, 0, 0, 1, 1, 2, 2, 2, 2, 3, 3, 4])
    to_v = np.array([2, 1, 0, 1, 0, 3, 2, 1, 0] + [np.inf] * 3)
    fails = episode <= 2
    score = np.array([0.1, 0.9, 0.8, 0.2, 0.3, 0.7, 0.1, 0.1, 0.1, 0.5, 0.95, 0.1])
    lt = lead_time(score, episode, to_v, fails, ~fails, recall=2 / 3)
    # peaks 0.9, 0.3, 0.7: the largest catching 2 of 3 is 0.7
    assert lt.threshold == 0.7 and lt.caught == pytest.approx(2 / 3)
    assert lt.steps == (1, 3) and lt.median_steps == 2.0
    assert lt.false_alarms_per_success == 0.5 and lt.successes_alarmed == 0.5
    full = lead_time(score, episode, to_v, fails, ~fails, recall=1.0)
    # episode 1 is caught only on its violating push: 0 steps ahead (the alarm comes
    # before the push executes, so a person called then could still take the arm)
    assert full.threshold == 0.3 and full.caught == 1.0 and full.steps == (0, 1, 3)
    with pytest.raises(ValueError, match="recall"):
        lead_time(score, episode, to_v, fails, ~fails, recall=0.0)


# ------------------------------------------------------------------ labels
def test_the_labels_of_the_policy_pushes_come_from_their_episodes() -> None:
    arm0 = [auto(), auto(), auto(violation=True), step("idle"), step("reset", 0),
            auto(goal=G2), auto(goal=G2, success=True), auto(goal=G1), auto(goal=G1)]
    arm1 = [auto(), teleop(), teleop(), auto(), auto(), auto(), auto(violation=True),
            step("idle"), step("idle")]
    frames = frames_of(arm0, arm1)
    c = classify(frames, 2, 1)
    score = np.arange(len(frames), dtype=float)
    p = policy_pushes(frames, c.classes, c.outcomes, c.episodes, {"s": score})
    # policy pushes: arm 0 at t 0, 1, 2, 5, 6, 7, 8; arm 1 at 0, 3, 4, 5, 6
    assert list(zip(p.arm.tolist(), p.t.tolist(), strict=True)) == [
        (0, 0), (1, 0), (0, 1), (0, 2), (1, 3), (1, 4), (0, 5), (1, 5), (0, 6), (1, 6),
        (0, 7), (0, 8)]
    assert p.to_violation.tolist() == [2, 6, 1, 0, 3, 2, np.inf, 1, np.inf, 0, np.inf,
                                       np.inf]
    assert p.scores["s"].tolist() == [0, 1, 2, 4, 7, 9, 10, 11, 12, 13, 14, 16]
    label, known = p.within(2)
    assert label.tolist() == [False, False, True, True, False, False, False, True, False,
                              True, False, False]
    # arm 0's last episode is open at t 7, 8 (the records end at 8): k = 2 sees t 7 only
    assert known.tolist() == [True] * 10 + [True, False]
    assert p.fails.tolist() == [True, True, True, True, True, True, False, True, False,
                                True, False, False]
    ids, peaks = p.episode_max("s", EpisodeOutcome.SUCCESS)
    assert peaks.tolist() == [12.0] and ids.size == 1
    with pytest.raises(ValueError, match="horizon"):
        p.within(0)


# ------------------------------------------------------------------ conformal
def test_the_threshold_is_the_conformal_order_statistic() -> None:
    peaks = np.arange(1.0, 20.0)  # 19 episodes
    assert conformal_threshold(peaks, 0.05) == 19.0  # k = ceil(20 * 0.95) = 19
    assert conformal_threshold(peaks, 0.1) == 18.0
    assert conformal_threshold(peaks[:18], 0.05) == math.inf  # k = 19 > 18
    assert episodes_needed(0.05) == 19 and episodes_needed(0.1) == 9
    for bad in (0.0, 1.0, -0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match=r"alpha must be in \(0, 1\)"):
            conformal_threshold(peaks, bad)
    with pytest.raises(ValueError, match="window"):
        ConformalAlarm(0.05, window=10)


@pytest.mark.parametrize("alpha", [0.05, 0.1, 0.2])
def test_the_false_alarm_rate_on_held_out_successes_is_at_most_alpha(alpha: float) -> None:
    rng = np.random.default_rng(2)
    peaks = rng.gamma(2.0, size=400)
    split = replay_split(peaks, alpha, splits=2000)  # a sanity check of the arithmetic
    assert split.rate <= alpha + 2 * split.mc_error
    assert split.rate >= alpha - 1 / 201 - 2 * split.mc_error  # and not far below
    online = replay_online([peaks], alpha, window=100, kind="split")
    assert online.judged == (400 - episodes_needed(alpha),)
    # exchangeable: P(fire) <= alpha for each episode, so the count is at most a
    # binomial(judged, alpha)'s 99.9 % quantile
    from scipy import stats

    assert online.fired[0] <= stats.binom.ppf(0.999, online.judged[0], alpha)


def test_the_online_alarm_follows_a_policy_whose_scores_fall_and_resumes_its_state() -> None:
    alarm = ConformalAlarm(0.1, window=20)
    assert not alarm.ready and not alarm.fires([1e9]).any()
    for p in np.linspace(10, 11, 20):
        alarm.add(float(p), fired=False)
    assert alarm.ready and 10.0 < alarm.threshold <= 11.0
    assert alarm.judged == 11  # the 10th to the 20th: 9 calibrate first (1/alpha - 1)
    for p in np.linspace(1, 2, 20):  # the policy learned: its scores fell
        alarm.add(float(p))
    assert alarm.threshold <= 2.0 and alarm.fires([2.5, 1.0]).tolist() == [True, False]
    again = ConformalAlarm(0.1, window=20)
    again.load_state_dict(alarm.state_dict())
    assert again.threshold == alarm.threshold and again.calibrated_on == 20
    assert again.judged == alarm.judged == 11


def test_the_failure_head_learns_which_signals_foretell_a_failure() -> None:
    from testbed.monitor.failure_head import FailureHead, design

    rng = np.random.default_rng(4)
    n = 3000
    scores = {"uncertainty": rng.random(n), "ood": rng.gamma(2.0, size=n) / 2}
    logit = -4.0 + 3.0 * scores["uncertainty"] + 1.5 * scores["ood"]
    y = rng.random(n) < 1.0 / (1.0 + np.exp(-logit))
    x = design(scores, ["uncertainty", "ood"])
    head = FailureHead.fit(x[:2000], y[:2000], ["uncertainty", "ood"])
    p = head.predict(x[2000:])
    best = 1.0 / (1.0 + np.exp(-logit[2000:]))  # the true probability
    assert auroc(p, y[2000:]) > auroc(best, y[2000:]) - 0.02
    assert abs(p.mean() - y[2000:].mean()) < 0.03  # calibrated in the large
    with pytest.raises(ValueError, match="both outcomes"):
        FailureHead.fit(x[:10], np.zeros(10, bool), ["uncertainty", "ood"])


def test_the_failure_head_reads_features_and_comes_back_from_its_file(tmp_path: Path) -> None:
    """A head on a signal and trunk features: it finds the feature that foretells the
    failure, its file gives the same scores, and a file it cannot use says why."""
    from testbed.monitor.failure_head import FailureHead, HeadError, design

    rng = np.random.default_rng(5)
    n, d = 4000, 8
    feats = rng.normal(size=(n, d))
    risk = rng.random(n) / 2
    logit = -3.0 + 2.5 * feats[:, 3] + 2.0 * risk
    y = rng.random(n) < 1.0 / (1.0 + np.exp(-logit))
    x = design({"risk": risk}, ["risk"], feats)
    assert x.shape == (n, 2 + d)
    head = FailureHead.fit(x[:3000], y[:3000], ["risk"], features=d, k=3)
    p = head.predict(x[3000:])
    assert auroc(p, y[3000:]) > auroc(risk[3000:], y[3000:]) + 0.15
    assert int(np.argmax(np.abs(head.weights[2:]))) == 3  # the feature that matters
    again = FailureHead.load(head.save(tmp_path / "head.json"))
    np.testing.assert_allclose(again.score({"risk": risk[3000:]}, feats[3000:]), p)
    assert (again.inputs, again.features, again.k) == (("risk",), d, 3)
    with pytest.raises(ValueError, match="8 trunk features"):
        again.score({"risk": risk[:2]}, feats[:2, :5])
    (tmp_path / "bad.json").write_text('{"format": "something-else"}')
    (tmp_path / "torn.json").write_text('{"format": "failure-head/1", "k"')
    short = {**head.to_json(), "weights": [0.0]}
    (tmp_path / "short.json").write_text(json.dumps(short))
    for name, words in [("missing.json", "cannot read"), ("bad.json", "not a failure-head/1"),
                        ("torn.json", "not JSON"), ("short.json", "do not match")]:
        with pytest.raises(HeadError, match=words):
            FailureHead.load(tmp_path / name)
