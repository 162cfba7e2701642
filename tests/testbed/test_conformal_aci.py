"""The alarm's guarantee (issue 45, item 2): adaptive conformal inference's level moves by
gamma (alpha - err) and its realised false-alarm rate stays within the stated bound for
any sequence of peaks, upward drift included, where the windowed split alarm's goes well
above alpha; its state survives a checkpoint; the realised rate's upper bound is
clustered by run."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from testbed.monitor.conformal import (
    AdaptiveAlarm,
    ConformalAlarm,
    aci_bounds,
    check_gamma,
    level_threshold,
    make_alarm,
    replay_online,
    replay_split,
)
from testbed.monitor.false_alarms import alarm_rate

ALPHA, GAMMA, WINDOW = 0.05, 0.05, 200


def test_the_threshold_at_any_level_is_the_order_statistic_or_never_or_always() -> None:
    peaks = np.arange(1.0, 20.0)  # 19 peaks
    assert level_threshold(peaks, 0.05) == 19.0  # k = ceil(20 * 0.95) = 19
    assert level_threshold(peaks, 0.5) == 10.0  # k = 10
    assert level_threshold(peaks, 0.049) == math.inf  # k = ceil(19.02) = 20 > 19
    assert level_threshold(peaks, 0.0) == level_threshold(peaks, -0.3) == math.inf
    assert level_threshold(peaks, 1.0) == level_threshold(peaks, 1.2) == -math.inf
    assert level_threshold(peaks, 0.96) == 1.0  # k = ceil(0.8) = 1: the smallest


def test_the_bound_is_the_stated_formula() -> None:
    # high: alpha + (alpha + A gamma (1 - alpha)) / (gamma T)
    # low: alpha - (1 - alpha + A gamma alpha) / (gamma T)
    low, high = aci_bounds(0.05, 0.05, 80)
    assert high == pytest.approx(0.05 + 0.0975 / 4.0) and high == pytest.approx(0.074375)
    assert low == pytest.approx(0.05 - 0.9525 / 4.0)
    assert aci_bounds(0.05, 0.05, 80, arms=4)[1] == pytest.approx(0.05 + 0.24 / 4.0)
    assert aci_bounds(0.1, 0.5, 0) == (-math.inf, math.inf)
    for bad in (0.0, -0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match=r"gamma must be in \(0, 1\]"):
            check_gamma(bad)
    with pytest.raises(ValueError, match="alarm must be one of aci, split"):
        make_alarm("weighted", 0.1, 20)


def test_the_level_moves_by_gamma_times_alpha_minus_err() -> None:
    """alpha 0.5 needs 1 peak; each judged episode moves a_t by 0.1 (0.5 - fired)."""
    alarm = AdaptiveAlarm(0.5, window=4, gamma=0.1)
    alarm.add(1.0, fired=True)  # not ready before it: calibrates only, not judged
    assert (alarm.judged, alarm.a_t) == (0, 0.5) and alarm.ready
    assert alarm.threshold == 1.0  # one peak, k = ceil(2 * 0.5) = 1
    alarm.add(2.0, fired=True)
    assert alarm.a_t == pytest.approx(0.45) and (alarm.judged, alarm.fired) == (1, 1)
    assert alarm.threshold == 2.0  # peaks 1, 2: k = ceil(3 * 0.55) = 2
    alarm.add(0.5, fired=False)
    assert alarm.a_t == pytest.approx(0.5)  # 0.45 + 0.1 * 0.5
    assert alarm.threshold == 1.0  # peaks 0.5, 1, 2: k = ceil(4 * 0.5) = 2
    alarm.add(3.0)  # fired not given: calibrates, not judged
    assert alarm.judged == 2 and alarm.calibrated_on == 4
    split = ConformalAlarm(0.5, window=4)
    for p, f in ((1.0, True), (2.0, True), (0.5, False)):
        split.add(p, fired=f)
    assert split.level == 0.5 and (split.judged, split.fired) == (1 + 1, 1)
    with pytest.raises(ValueError, match="finite"):
        alarm.add(-math.inf, fired=False)


def drifting(runs: int, episodes: int, seed: int) -> list[np.ndarray]:
    """Peaks whose scale rises by e^kappa per episode: exp(kappa t + U_t), U_t ~ U(0, 1),
    kappa = 0.5 / WINDOW (the scale grows e^0.5 = 1.65x across one window)."""
    rng = np.random.default_rng(seed)
    t = np.arange(episodes)
    return [np.exp(0.5 / WINDOW * t + rng.random(episodes)) for _ in range(runs)]


def test_with_upward_drifting_peaks_the_window_alarm_fails_and_aci_keeps_its_bound() -> None:
    """Why the windowed alarm fails, by reasoning: the threshold is order-invariant, so
    take logs. A full window holds kappa (t - j) + U, j = 1..200: relative to the new
    episode, U - 0.5 V with V ~ U(0, 1). Its threshold is its 191st smallest of 200
    (k = ceil(201 x 0.95)), about its quantile with tail 10/201 = 0.0498;
    P(U - 0.5 V > q) = (1 - q)^2 for q in [0.5, 1], so 1 - q = sqrt(0.0498) = 0.223, and
    the new episode's U exceeds q with probability 0.223, four times alpha (a little
    less over the 200 episodes while the window fills, when the drift in it is smaller).
    ACI's rate is pinned by the identity whatever the peaks do."""
    runs = drifting(4, 3000, seed=45)
    old = replay_online(runs, ALPHA, WINDOW, kind="split")
    new = replay_online(runs, ALPHA, WINDOW, kind="aci", gamma=GAMMA)
    judged = 3000 - 19  # each run judges from its 20th episode (19 calibrate first)
    assert old.judged == new.judged == (judged,) * 4
    assert old.rate.rate == pytest.approx(0.223, abs=0.02)
    assert not old.holds and old.rate.rate > 4 * ALPHA - 0.05
    low, high = aci_bounds(ALPHA, GAMMA, judged)
    for fired in new.fired:
        assert low <= fired / judged <= high  # the theorem, per run
    assert new.within_guarantee and new.guarantee == (pytest.approx(high),) * 4
    assert high < 0.051 and old.rate.rate > 4 * high  # the two differ by a factor 4


def test_on_exchangeable_peaks_both_alarms_are_near_alpha() -> None:
    rng = np.random.default_rng(2)
    runs = [rng.gamma(2.0, size=1000) for _ in range(4)]
    split = replay_online(runs, ALPHA, WINDOW, kind="split")
    aci = replay_online(runs, ALPHA, WINDOW, kind="aci", gamma=GAMMA)
    low, high = aci_bounds(ALPHA, GAMMA, 1000 - 19)
    assert all(low <= f / 981 <= high for f in aci.fired)
    # split: P(fire) = (n + 1 - k) / (n + 1) for n in 19..200 peaks: 1/20 at n = 19,
    # 10/201 from n = 200; the pooled rate of 3924 episodes is within 3 binomial errors
    assert abs(split.rate.rate - 0.0499) < 3 * math.sqrt(0.05 * 0.95 / 3924)
    # the sanity check (cannot fail: the halves are a permutation of pooled peaks)
    check = replay_split(np.concatenate(runs), ALPHA, splits=200)
    assert abs(check.rate - ALPHA) < 0.005 and check.splits == 200


def test_a_resumed_aci_alarm_goes_on_as_the_unbroken_one() -> None:
    """Checkpointed mid-sequence (JSON, as state.json keeps it) and restored, the alarm
    judges the rest of the episodes exactly as the one never stopped: same level, same
    threshold and counts after every episode."""
    peaks = drifting(1, 400, seed=7)[0]
    a = AdaptiveAlarm(ALPHA, WINDOW, GAMMA)
    for p in peaks[:250].tolist():
        a.add(p, bool(a.fires([p])[0]))
    b = AdaptiveAlarm(ALPHA, WINDOW, GAMMA)
    b.load_state_dict(json.loads(json.dumps(a.state_dict(), allow_nan=False)))
    assert b.a_t == a.a_t and b.a_t != ALPHA and b.threshold == a.threshold
    for p in peaks[250:].tolist():
        fa, fb = bool(a.fires([p])[0]), bool(b.fires([p])[0])
        assert fa == fb
        a.add(p, fa)
        b.add(p, fb)
        assert (b.a_t, b.threshold, b.judged, b.fired) == (a.a_t, a.threshold, a.judged,
                                                            a.fired)


def test_a_checkpoint_from_before_issue_45_loads() -> None:
    """An old run's state.json "alarm": alpha, window and peaks (null: no policy push)."""
    old = {"alpha": 0.1, "window": 20, "peaks": [0.3, None, 0.1, 0.2] + [0.5] * 6}
    for alarm in (AdaptiveAlarm(0.1, 20), ConformalAlarm(0.1, 20)):
        alarm.load_state_dict(old)
        assert alarm.calibrated_on == 9 and alarm.ready  # the null dropped
        assert alarm.threshold == 0.5 and alarm.level == 0.1 and alarm.judged == 0


def test_the_upper_bound_is_clopper_pearson_for_one_run_and_clustered_for_several() -> None:
    one = alarm_rate([0], [59], 0.05)
    assert one.upper == pytest.approx(1 - 0.05 ** (1 / 59))  # CP at 0 events
    assert one.method.startswith("Clopper-Pearson") and one.runs == 1
    # two runs with the same rate: no between-run excess (design effect 1), but only one
    # degree of freedom: n_eff = 200 (z / t_1)^2
    two = alarm_rate([0, 0], [100, 100], 0.05)
    n_eff = 200 * (stats.norm.ppf(0.95) / stats.t.ppf(0.95, 1)) ** 2
    assert two.upper == pytest.approx(1 - 0.05 ** (1 / n_eff))
    # the same 20 alarms in 200, spread evenly or all in one run: the clustered bound is
    # wider when the runs disagree (a binomial one would not see the difference)
    even, lumped = alarm_rate([10, 10, 10], [100] * 3, 0.5), alarm_rate([30, 0, 0], [100] * 3, 0.5)
    assert even.rate == lumped.rate == 0.1 and lumped.upper > even.upper
    assert "design effect 1.00" in even.method and "design effect 1.00" not in lumped.method
    assert alarm_rate([1, 0], [3, 0], 0.05).runs == 1  # a run that judged none is left out
    assert math.isnan(alarm_rate([0], [0], 0.05).upper)
    with pytest.raises(ValueError, match="fired <= judged"):
        alarm_rate([3], [2], 0.05)


def test_the_clustered_bound_covers_where_the_binomial_one_does_not() -> None:
    """Runs whose alarm rates differ (Beta(2, 38): mean 0.05, intra-run correlation
    1/41), 6 runs of 80 episodes: the design effect is 1 + 79/41 = 2.9, so a binomial
    standard error is sqrt(2.9) = 1.7 times too small and its one-sided 95 % bound covers
    the mean about Phi(1.645 / 1.7) = 83 % of the time (normal approximation); the same
    criterion, the nominal 95 % less three Monte-Carlo errors over 400 replicates
    (0.917), is met by the clustered bound and failed by the binomial one."""
    rng = np.random.default_rng(11)
    covered = naive = 0
    for _ in range(400):
        p = rng.beta(2.0, 38.0, size=6)
        fired = rng.binomial(80, p)
        r = alarm_rate(fired.tolist(), [80] * 6, 0.05)
        covered += r.upper >= 0.05
        se = math.sqrt(max(r.rate * (1 - r.rate), 0.0) / 480)
        naive += r.rate + 1.645 * se >= 0.05
    assert covered / 400 >= 0.917
    assert naive / 400 < 0.917 - 0.03


def test_the_live_rate_is_read_from_the_rows_untouched_and_touched_apart(tmp_path: Path) -> None:
    """A monitor run by hand, arm 0: a success before the alarm was ready (not judged),
    an untouched success the alarm fired in (key a at a policy push), one it did not, and
    a success after a teleop the alarm had called (touched: counted apart)."""
    from testbed.records.step_record import StepRecord
    from testbed.records.steps import RunWriter
    from testbed.records.store import RunDataWriter
    from testbed.results.report_alarm import false_alarm_table, live_alarm
    from tests.testbed.test_frame_classes_records import G1, G2, auto, frames_of, step, teleop

    arm0 = [auto(goal=G1), auto(goal=G1, success=True),
            auto(goal=G2), auto(goal=G2, success=True),
            auto(goal=G1), auto(goal=G1, success=True),
            auto(goal=G2), teleop(goal=G2), auto(goal=G2, success=True)]
    arm1 = [step("idle", goal=G1) for _ in arm0]
    alarmed = {2, 6}  # arm 0's key a
    frames = frames_of(arm0, arm1)
    run = tmp_path / "m"
    run.mkdir()
    data = RunDataWriter(run, ["c/left", "c/right"])
    with RunWriter(run) as w:
        for t in range(len(arm0)):
            row = {"t": t, "wall_time": 1.7e9 + t, "duration_s": 1.0, "robots": []}
            for a, p in enumerate((arm0, arm1)):
                mon = {"alarm_score": 0.5} | ({"alarm_level": 0.05} if t >= 2 else {})
                row["robots"].append({
                    "robot": ["c/left", "c/right"][a], "mode": p[t]["mode"],
                    "human": p[t]["human"], "action": p[t]["action"],
                    "success": p[t]["success"], "violation": p[t]["violation"],
                    "uncertainty": 0.1, "risk": 0.1, "monitor": mon,
                    "key": [0.0, 1.0 if a == 0 and t in alarmed else 0.0, 0.0, 0.0, 0.0]})
            f = frames[t * 2:(t + 1) * 2]
            data.append(StepRecord.from_row(row, 0, np.zeros((2, 64, 64, 3), np.uint8),
                                            f["observed"], f["goal"]).to_frames())
            w.write_step(row)
    data.close()
    live = live_alarm(run)
    assert live is not None
    assert (live.judged, live.fired, live.touched, live.touched_fired) == (2, 1, 1, 1)
    assert live.arms == 2 and live.config.alarm == "aci"
    assert live.guarantee == pytest.approx(aci_bounds(0.05, 0.05, 2, arms=2)[1])
    table = false_alarm_table({"monitor": [run]})
    assert table is not None
    upper = stats.beta.ppf(0.95, 2, 1)  # Clopper-Pearson, 1 of 2 in one run
    assert table.rows[0][4:7] == ["2", f"0.500 [{upper:.3f}] (1)", "no"]
    assert table.rows[0][8:] == ["1", "1.000 (1)"]
