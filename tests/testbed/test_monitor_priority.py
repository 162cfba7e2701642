"""Allocation by the failure monitor (issue 36, item 4): C.U.R. until the alarm has its
successful episodes, then a person only where the alarm fires, the highest score first;
episode peaks follow the rules of the labels; its state survives a checkpoint."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from testbed.experiments.theta0 import CACHE
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import get_algorithm
from testbed.fleet.monitor_priority import MONITOR_READS, MonitorPriority
from testbed.fleet.priorities import PrioritySignals
from testbed.monitor.monitor_config import SCORES, MonitorConfig
from testbed.records.steps import read_steps
from testbed.records.store import FRAME_DTYPE, MODES

N = 3
ROOT = Path(__file__).resolve().parents[2]


def signals(t: int, u: list[float], *, violating: list[bool] | None = None,
            risk: list[float] | None = None, ood: list[float] | None = None
            ) -> PrioritySignals:
    return PrioritySignals(t=t, violating=np.array(violating or [False] * N),
                           uncertainty=np.array(u), risk=np.array(risk or [0.0] * N),
                           novelty=np.zeros(N), ood=np.array(ood or [1.0] * N))


def frames(modes: list[str], *, success: list[bool] | None = None,
           violation: list[bool] | None = None, goal: float = 0.5) -> np.ndarray:
    f = np.zeros(N, FRAME_DTYPE)
    f["mode"] = [MODES.index(m) for m in modes]
    f["action"] = [1 if m in ("autonomous", "teleop") else -1 for m in modes]
    f["observed"] = True
    f["success"] = success or [False] * N
    f["violation"] = violation or [False] * N
    f["goal"] = goal
    return f


def test_it_runs_as_cur_until_its_alarm_is_ready_then_only_where_the_alarm_fires() -> None:
    p = MonitorPriority(N, score="uncertainty", alpha=0.1, window=50, u_hat=0.2, r_hat=0.5)
    keys = p.keys(signals(0, [0.1, 0.3, 0.9], risk=[0.6, 0.0, 0.0]))
    assert keys.tolist() == [[0, 0, 0, 0, 0.6], [0, 0, 0, 0.3, 0], [0, 0, 0, 0.9, 0]]
    # nine successful episodes of arm 0 with peaks 0.1 .. 0.5 (alpha 0.1 needs 9)
    for k in range(9):
        peak = 0.1 + 0.05 * k
        p.keys(signals(2 * k + 1, [peak / 2, 0.0, 0.0]))
        p.observe(frames(["autonomous", "idle", "idle"]))
        p.keys(signals(2 * k + 2, [peak, 0.0, 0.0]))
        assert not p.alarm.ready
        p.observe(frames(["autonomous", "idle", "idle"], success=[True, False, False]))
    assert p.alarm.ready and p.alarm.threshold == 0.5  # k = ceil(10 * 0.9) = 9: the largest
    keys = p.keys(signals(30, [0.45, 0.7, 0.9], violating=[True, False, False]))
    # arm 0 violating: its reset first; arms 1 and 2 alarmed, ranked by their score;
    # u and r no longer count
    assert keys.tolist() == [[1, 0, 0, 0, 0], [0, 1, 0.7, 0, 0], [0, 1, 0.9, 0, 0]]
    assert p.keys(signals(31, [0.45, 0.5, 0.1])).tolist() == [[0] * 5] * 3  # trusted
    assert p.row_fields(0) == {"alarm_score": 0.45, "alarm_threshold": 0.5,
                               "alarm_level": 0.1}  # ACI: nothing judged yet, a_1 = alpha


def test_a_peak_counts_only_when_its_episode_succeeds() -> None:
    p = MonitorPriority(N, score="uncertainty", alpha=0.5, window=10, u_hat=1, r_hat=1)
    auto = ["autonomous"] * N
    p.keys(signals(0, [0.9, 0.8, 0.7]))
    p.observe(frames(auto, violation=[True, False, False]))  # arm 0's episode failed
    p.keys(signals(1, [0.1, 0.2, 0.3]))
    p.observe(frames(auto, goal=0.7))  # a new goal: arms 1 and 2 start again
    p.keys(signals(2, [0.4, 0.25, 0.35]))
    p.observe(frames(["autonomous", "teleop", "autonomous"], goal=0.7,
                     success=[True, True, True]))
    # arm 0: 0.4 (the failed episode's 0.9 was dropped); arm 1: none (a person had the
    # arm: a touched success does not calibrate, issue 45); arm 2: max(0.3, 0.35)
    assert sorted(p.alarm.state_dict()["peaks"]) == [0.35, 0.4]


def test_a_touched_success_does_not_calibrate_and_an_alarm_nobody_answered_is_judged() -> None:
    """Issue 45, item 2: a success in which a person had the arm (teleop or reset) adds
    no peak; once ready, an untouched success in which the alarm fired at a policy push
    moves ACI's level by gamma (alpha - 1); the reset after a violation is the violated
    episode's, not a touch of the next one."""
    p = MonitorPriority(N, score="uncertainty", alpha=0.5, window=10, u_hat=1, r_hat=1,
                        gamma=0.1)
    p.keys(signals(0, [0.3, 0.6, 0.2]))
    p.observe(frames(["autonomous", "autonomous", "autonomous"], violation=[False, False, True]))
    p.keys(signals(1, [0.4, 0.0, 0.0]))
    p.observe(frames(["autonomous", "teleop", "reset"], success=[True, True, False]))
    # arm 0: untouched, peak 0.4 (not ready before: calibrates only); arm 1: touched
    assert p.alarm.state_dict()["peaks"] == [0.4] and p.alarm.ready and p.alarm.judged == 0
    p.keys(signals(2, [0.1, 0.9, 0.7]))  # ready: threshold 0.4 (k = ceil(2 * 0.5) = 1)
    assert p.keys(signals(2, [0.1, 0.9, 0.7]))[:, 1].tolist() == [0.0, 1.0, 1.0]
    # arm 1 (alarmed, nobody came) and arm 2 (its first push after the reset) succeed
    p.observe(frames(["autonomous", "autonomous", "autonomous"], success=[False, True, True]))
    assert p.alarm.judged == 2 and p.alarm.fired == 2
    assert p.alarm.level == pytest.approx(0.5 + 2 * 0.1 * (0.5 - 1.0))
    assert sorted(p.alarm.state_dict()["peaks"]) == [0.4, 0.7, 0.9]


def test_a_state_from_before_issue_45_loads_and_a_resumed_one_goes_on_alike() -> None:
    p = MonitorPriority(N, score="uncertainty", alpha=0.5, window=10, u_hat=1, r_hat=1)
    rng = np.random.default_rng(5)
    steps = [(rng.random(N).tolist(), (rng.random(N) < 0.3).tolist(),
              ["teleop" if x < 0.1 else "autonomous" for x in rng.random(N)])
             for _ in range(60)]
    for t, (u, succ, modes) in enumerate(steps[:30]):
        p.keys(signals(t, u))
        p.observe(frames(modes, success=succ))
    q = MonitorPriority(N, score="uncertainty", alpha=0.5, window=10, u_hat=1, r_hat=1)
    q.load_state_dict(json.loads(json.dumps(p.state_dict(), allow_nan=False)))
    for t, (u, succ, modes) in enumerate(steps[30:], start=30):
        assert np.array_equal(q.keys(signals(t, u)), p.keys(signals(t, u)))
        p.observe(frames(modes, success=succ))
        q.observe(frames(modes, success=succ))
        assert q.alarm.state_dict() == p.alarm.state_dict()
    assert p.alarm.judged > 10 and p.alarm.level != 0.5  # it judged and moved
    old = {k: v for k, v in p.state_dict().items()
           if k not in ("touched", "fired", "violated", "alarmed")}
    old["alarm"] = {"alpha": 0.5, "window": 10, "peaks": [0.2, None, 0.6]}
    r = MonitorPriority(N, score="uncertainty", alpha=0.5, window=10, u_hat=1, r_hat=1)
    r.load_state_dict(old)
    assert r.alarm.calibrated_on == 2 and r.alarm.level == 0.5 and r.alarm.ready


def test_ood_u_is_high_only_where_both_are() -> None:
    p = MonitorPriority(N, score="ood_u", alpha=0.5, window=10, u_hat=1, r_hat=1)
    for t in range(10):  # a reference of policy pushes: ood and u both 0..1
        v = t / 10
        p.keys(signals(t, [v] * N, ood=[v] * N))
        p.observe(frames(["autonomous"] * N))
    score = p.scores(signals(10, [0.9, 0.9, 0.09], ood=[0.9, 0.09, 0.9]))
    # each over its reference's median (0.45): both high -> 2; either low -> 0.2
    np.testing.assert_allclose(score, [2.0, 0.2, 0.2])


def test_its_state_is_json_and_comes_back() -> None:
    p = MonitorPriority(N, score="ood_u", alpha=0.5, window=10, u_hat=1, r_hat=1)
    for t in range(6):
        p.keys(signals(t, [0.1 * t] * N, ood=[1.0 - 0.1 * t] * N))
        p.observe(frames(["autonomous", "idle", "autonomous"],
                         success=[t % 2 == 1, False, t == 5]))
    state = json.loads(json.dumps(p.state_dict(), allow_nan=False))
    q = MonitorPriority(N, score="ood_u", alpha=0.5, window=10, u_hat=1, r_hat=1)
    q.load_state_dict(state)
    s = signals(6, [0.3, 0.6, 0.9], ood=[0.9, 0.6, 0.3])
    assert np.array_equal(q.keys(s), p.keys(s))
    assert q.alarm.threshold == p.alarm.threshold


def test_the_registry_builds_it_from_the_monitor_config_and_it_reads_what_it_declares() -> None:
    params = AlgorithmConfig(u_hat=0.2, r_hat=0.5)
    algo = get_algorithm("monitor", params, N, 1, 0, MonitorConfig(score="ood", alpha=0.2))
    assert algo.spec.reads == MONITOR_READS and algo.spec.critics == {"safety"}
    assert algo.priority.alarm.alpha == 0.2  # type: ignore[attr-defined]
    for score in SCORES:
        assert MonitorPriority.reads_of(score) <= MONITOR_READS
    with pytest.raises(ValueError):
        MonitorConfig(score="goal_risk")  # type: ignore[arg-type]


def test_with_a_failure_head_its_score_is_the_heads_on_the_arms_features() -> None:
    """score = "fail_head": each arm's score is the head's P(violation within k) from its
    risk and its trunk features, the alarm fires on it, and without features it refuses."""
    from testbed.monitor.failure_head import FailureHead

    head = FailureHead(("risk",), np.zeros(4), np.ones(4), np.array([0.0, 0.0, 3.0, -1.0]),
                       -1.0, features=2)
    p = MonitorPriority(N, score="fail_head", alpha=0.5, window=10, u_hat=1, r_hat=1,
                        head=head)
    feats = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 1.0]])

    def s(t: int, features: np.ndarray | None = feats) -> PrioritySignals:
        return PrioritySignals(t=t, violating=np.zeros(N, bool), uncertainty=np.zeros(N),
                               risk=np.full(N, 0.2), novelty=np.zeros(N), ood=np.ones(N),
                               features=features)

    want = 1 / (1 + np.exp(-(3.0 * feats[:, 0] - feats[:, 1] - 1.0)))
    np.testing.assert_allclose(p.scores(s(0)), want)
    for t in range(4):  # successes whose peaks are the first arm's score: the threshold
        p.keys(s(t))
        p.observe(frames(["autonomous", "idle", "idle"], success=[t % 2 == 1, False, False]))
    assert p.alarm.ready
    keys = p.keys(s(4))
    assert keys[:, 1].tolist() == [0.0, 1.0, 1.0] and keys[2, 2] > keys[1, 2]
    with pytest.raises(ValueError, match="features is required"):
        p.keys(s(5, None))
    with pytest.raises(ValueError, match="only then"):
        MonitorPriority(N, score="risk", alpha=0.5, window=10, u_hat=1, r_hat=1, head=head)


def test_testbed_plan_reads_a_monitor_run_as_resets_first() -> None:
    """The plan's batch allocator replays Algorithm 1 on requests fitted from a run's own
    keys (docs/notes/plan.md): a monitor run's alarms are its requests, and its resets sort
    before them, as C.U.R.'s do."""
    from testbed.planning.plan_fit import key_order

    assert key_order("monitor") == key_order("cur") == "resets_first"


@pytest.fixture(scope="module")
def theta0_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Where the first of the two twin trials below leaves its theta_0 cache for the
    other: both pretrain the same theta_0 (its key: the learning config, the arms, t_R
    and the seed; not the monitor's fields), and a trial is the same with the cache cold
    or warm (``testbed.experiments.learners.pretrained_learner``), which is not what
    these tests check. Kept under its key, so a config that differs pretrains anew."""
    return tmp_path_factory.mktemp("monitor-theta0")


def _take_cache(runs: Path, cache: Path) -> None:
    """Start ``runs`` with the module's theta_0 cache, where an earlier test made it."""
    if (cache / CACHE).is_dir():
        shutil.copytree(cache / CACHE, runs / CACHE)


def _keep_cache(runs: Path, cache: Path) -> None:
    """Leave the theta_0 ``runs`` pretrained for the module's other twin trial."""
    if (runs / CACHE).is_dir() and not (cache / CACHE).exists():
        shutil.copytree(runs / CACHE, cache / CACHE)


@pytest.mark.slow
def test_a_twin_trial_of_the_monitor_records_its_alarm_and_the_report_says_so(
        tmp_path: Path, theta0_cache: Path) -> None:
    """The monitor end to end on the twin: C.U.R.'s rule until its alarm is ready (alpha
    0.2: 4 successful episodes), then its score and threshold in every arm's row, and the
    report's table of it at work. The alarm calibrates on successes no person touched
    (issue 45), so theta_0 must succeed on its own: 150 demonstrations and 150 steps (at
    60 and 10 no untouched success came in 40 steps; at these, seed 3 is ready at step 16
    with 7 of them)."""
    (tmp_path / "small.toml").write_text(
        '[trial]\nsteps = 40\nseed = 3\n[learning]\nensemble_size = 2\nbatch_size = 32\n'
        'demos = 150\ncritic_transitions = 40\npretrain_steps = 150\n[monitor]\nalpha = 0.2\n')
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    _take_cache(tmp_path / "runs", theta0_cache)
    run = subprocess.run([sys.executable, "-m", "testbed.cli", "trial", "--config",
                          "small.toml", "--algorithm", "monitor", "--out", "runs", "--name",
                          "m"], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                         env=env)
    assert run.returncode == 0, run.stderr[-3000:]
    _keep_cache(tmp_path / "runs", theta0_cache)
    rows = read_steps(tmp_path / "runs" / "m" / "steps.jsonl")
    entries = [r for row in rows for r in row["robots"] if r["mode"] != "fault"]
    assert all("alarm_score" in r["monitor"] and "ood" in r["monitor"] for r in entries)
    ready = [row["t"] for row in rows
             if any("alarm_level" in r.get("monitor", {}) for r in row["robots"])]
    assert ready and ready == list(range(ready[0], 40))  # ready once, then for good
    before = [r for row in rows[:ready[0]] for r in row["robots"]]
    assert all(r["key"][1] == r["key"][2] == 0 for r in before)  # no alarm before
    after = [r for row in rows[ready[0]:] for r in row["robots"]]
    assert all(r["key"][3] == r["key"][4] == 0 for r in after)  # no C.U.R. after
    rep = subprocess.run([sys.executable, "-m", "testbed.cli", "report", "runs", "--out",
                          "rep"], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                         env=env)
    assert rep.returncode == 0, rep.stderr[-3000:]
    md = (tmp_path / "rep" / "report.md").read_text()
    table = md.partition("The monitor algorithm at work")[2].split("\n\n")[1]
    assert f"| m | {ready[0]} |" in table


@pytest.mark.slow
def test_a_monitor_trial_on_a_failure_head_killed_and_resumed_keeps_its_alarm(
        tmp_path: Path, theta0_cache: Path) -> None:
    """score = "fail_head" live, on the twin: the head reads each arm's trunk features
    from act. Killed with SIGKILL mid-trial: the alarm's state at the last checkpoint is
    the one an unbroken trial of the same seed has at that step, and the resumed trial
    goes on from it (ready at once where it was, every arm's score in every row)."""
    import signal
    import time

    from testbed.monitor.failure_head import FailureHead

    rng = np.random.default_rng(0)
    FailureHead(("risk",), np.zeros(66), np.ones(66), rng.normal(0, 0.3, 66), -2.0,
                features=64).save(tmp_path / "head.json")
    (tmp_path / "small.toml").write_text(
        '[trial]\nsteps = 40\nseed = 3\n[learning]\nensemble_size = 2\nbatch_size = 32\n'
        'demos = 150\ncritic_transitions = 40\npretrain_steps = 150\n[monitor]\nalpha = 0.2\n'
        'score = "fail_head"\nhead = "head.json"\n')
    env = {**os.environ, "PYTHONPATH": str(ROOT)}

    def trial(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "testbed.cli", "trial", *args],
                              cwd=tmp_path, capture_output=True, text=True, timeout=300,
                              env=env)

    run = tmp_path / "runs" / "k"
    _take_cache(tmp_path / "runs", theta0_cache)
    proc = subprocess.Popen(
        [sys.executable, "-m", "testbed.cli", "trial", "--config", "small.toml", "--algorithm",
         "monitor", "--out", "runs", "--name", "k"], cwd=tmp_path, env=env,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline:
        p = run / "steps.jsonl"
        if p.exists() and p.read_text().count("\n") >= 25:
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    state = json.loads((run / "state.json").read_text())
    t = int(state["t"])
    assert 20 <= t < 39
    ref = trial("--config", "small.toml", "--algorithm", "monitor", "--out", "runs", "--name",
                "ref", "--steps", str(t + 1))
    assert ref.returncode == 0, ref.stderr[-3000:]
    _keep_cache(tmp_path / "runs", theta0_cache)
    ref_state = json.loads((tmp_path / "runs" / "ref" / "state.json").read_text())
    killed_alarm = state["algorithm"]["priority"]
    assert killed_alarm == ref_state["algorithm"]["priority"]
    assert len(killed_alarm["alarm"]["peaks"]) >= 4  # ready (alpha 0.2) before the kill

    done = trial("--resume", str(run))
    assert done.returncode == 0, done.stderr[-3000:]
    rows = read_steps(run / "steps.jsonl")
    assert [r["t"] for r in rows] == list(range(40))
    scores = [e["monitor"]["alarm_score"] for row in rows for e in row["robots"]
              if e["mode"] != "fault"]
    assert all(0.0 < s < 1.0 for s in scores) and len(set(scores)) > 10  # the head's P
    ready = [row["t"] for row in rows
             if any("alarm_level" in e["monitor"] for e in row["robots"])]
    assert ready == list(range(ready[0], 40)) and ready[0] <= t  # ready before, and after
