"""End to end on the real parts: twin hosts in agent processes, torch, records.

A small learner (2 members, batch 32) keeps these fast; the loop, the hosts, the
allocator and the records are the real ones that the 250-step trial uses.
"""

from __future__ import annotations

import json
import os
import platform
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import tomli_w
import torch

from testbed.experiments.fleet_config import FleetConfig
from testbed.experiments.learners import resume_learner
from testbed.experiments.theta0 import CACHE
from testbed.learning import Learner
from testbed.records.metrics import summarize
from testbed.records.run_dir import RunDir
from testbed.records.steps import read_steps, validate_step
from testbed.records.store import RunData

ROOT = Path(__file__).resolve().parents[2]
PRODUCT = ("drivers", "gui", "sim_twin", "testbed", "pyproject.toml")  # drivers.build_id's

SMALL = {
    "trial": {"steps": 24, "seed": 3},
    "learning": {
        "ensemble_size": 2,
        "batch_size": 32,
        "demos": 60,
        "critic_transitions": 40,
        "pretrain_steps": 10,
    },
}


def _cli(*args: str, cwd: Path, timeout: float = 240) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "testbed.cli", *args],
        cwd=cwd, capture_output=True, text=True, timeout=timeout,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("trial")
    (d / "small.toml").write_text(tomli_w.dumps(SMALL))
    return d


@pytest.fixture(scope="module")
def cold_then_warm(workdir: Path) -> list[set[int]]:
    """Two 12-step trials of one seed into ``cold``: the first pretrains theta_0 on its
    own hosts (a cold cache), the second takes it from the cache; the agent processes
    each started. ``test_same_seed_same_records_cold_then_warm_one_agent_per_host``
    checks them; the other tests start from the theta_0 they made (``theta0``)."""
    agents = []
    for name in ("r1", "r2"):
        err = workdir / f"{name}.err"
        with open(err, "wb") as err_file:
            proc = subprocess.Popen(
                [sys.executable, "-m", "testbed.cli", "trial", "--config", "small.toml",
                 "--out", "cold", "--name", name, "--steps", "12"],
                cwd=workdir, stdout=subprocess.DEVNULL, stderr=err_file,
                env={**{k: v for k, v in os.environ.items() if k != "TESTBED_THREADS"},
                     "PYTHONPATH": str(ROOT)},  # the default threads (not a worker's share)
            )
            agents.append(_agents_of(proc))
        assert proc.wait(timeout=10) == 0, err.read_text()[-3000:]
    return agents


@pytest.fixture(scope="module")
def theta0(workdir: Path, cold_then_warm: list[set[int]]) -> Path:
    """The theta_0 cache the cold trial made, hard-linked into the other outputs' caches
    (``runs``, ``proto``): the small config pretrains the same theta_0 there (its key:
    the learning config, the robots, t_R, the seed, the critics; a protocol of bc and
    cur pretrains cur's critics), so pretraining it again would only repeat what the
    cold trial's records already prove. A cache hit is the product's own path (r2)."""
    cache = workdir / "cold" / CACHE
    assert any(cache.glob("*/learner.pt")), "the cold trial left no theta_0"
    for out in ("runs", "proto"):
        if not (workdir / out / CACHE).exists():
            shutil.copytree(cache, workdir / out / CACHE, copy_function=os.link)
    return cache


@pytest.mark.slow
def test_twin_trial_summary_equals_recomputation(workdir: Path, theta0: Path) -> None:
    proc = _cli("trial", "--config", "small.toml", "--out", "runs", "--name", "a", cwd=workdir)
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = workdir / "runs" / "a"
    steps = read_steps(run / "steps.jsonl")
    assert [s["t"] for s in steps] == list(range(24))
    for s in steps:
        validate_step(s)
        assert len(s["robots"]) == 4
        assert s["wall_time"] > 1.6e9 and 0 < s["duration_s"] < 60
    assert [s["wall_time"] for s in steps] == sorted(s["wall_time"] for s in steps)
    for host in ("cell0", "cell1"):  # each host's agent log, in the run folder
        assert (run / "hosts" / f"{host}.log").stat().st_size > 0
    meta = json.loads((run / "run.json").read_text())
    assert meta["status"] == "complete"
    _assert_code_and_hosts(meta, run)
    printed = json.loads(proc.stdout[proc.stdout.index("{"):])
    on_disk = json.loads((run / "summary.json").read_text())
    again = summarize(steps, algorithm="cur", num_humans=2, num_robots=4)
    for k in ("successes", "hard_resets", "idle_time", "human_actions", "rohe", "steps"):
        assert printed[k] == on_disk[k] == again[k], k
    modes = {r["mode"] for s in steps for r in s["robots"]}
    assert "autonomous" in modes and "teleop" in modes


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True,
                          check=True).stdout


def _assert_code_and_hosts(meta: dict[str, object], run: Path) -> None:
    """run.json says which code ran (this checkout's HEAD, dirty as git status says of
    the product) and which hosts (each twin host with the build its agent reported at
    hello, as its own log says)."""
    code = meta["code"]
    assert isinstance(code, dict)
    assert code["commit"] == _git("rev-parse", "HEAD").strip()
    assert code["dirty"] is bool(_git("status", "--porcelain", "--", *PRODUCT).strip())
    assert code["python"] == platform.python_version() and "numpy" in code["libraries"]
    hosts = meta["hosts"]
    assert isinstance(hosts, dict) and list(hosts) == ["cell0", "cell1"]
    for name, entry in hosts.items():
        assert entry == {"backend": "twin", "transport": "local", "build": code["build"],
                         "arms": ["left", "right"]}
        assert f"build {entry['build']}" in (run / "hosts" / f"{name}.log").read_text()


def _children(pid: int) -> list[int]:
    """The child pids of ``pid``: every thread's ``children`` list (the kernel's, a few
    bytes; scanning all of /proc at 50 Hz cost the test seconds of CPU on a busy
    machine), or a scan of /proc where the kernel keeps no such list."""
    proc = Path(f"/proc/{pid}")
    if not (proc / "task" / str(pid) / "children").exists():
        return _children_by_scan(pid) if proc.exists() else []
    kids: list[int] = []
    try:
        for task in (proc / "task").iterdir():
            try:
                kids.extend(int(c) for c in (task / "children").read_text().split())
            except OSError:
                continue  # that thread ended meanwhile
    except OSError:
        return []  # the process ended meanwhile
    return kids


def _children_by_scan(pid: int) -> list[int]:
    kids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                kids.append(int(d.name))
    return kids


def _agents_of(proc: subprocess.Popen[bytes], timeout_s: float = 240) -> set[int]:
    """Pids of the agent processes ``proc`` starts (local transport: its children), seen
    by polling its children until it exits; an agent lives for its whole trial, so none
    is missed."""
    seen: set[int] = set()
    deadline = time.monotonic() + timeout_s
    while proc.poll() is None and time.monotonic() < deadline:
        for kid in _children(proc.pid):
            if kid in seen:
                continue
            try:  # read again each time: a child not yet exec'd shows its parent's
                cmdline = Path(f"/proc/{kid}/cmdline").read_bytes()
            except OSError:
                continue
            if b"drivers.agent" in cmdline:
                seen.add(kid)
        time.sleep(0.02)
    return seen


def _without_timing(text: str) -> str:
    """The log minus ``wall_time``/``duration_s``: the only fields two runs of a seed may
    differ in (docs/ARCHITECTURE.md, "Run records")."""
    return re.sub(r',"wall_time":[^,}]*,"duration_s":[^,}]*', "", text)


@pytest.mark.slow
def test_same_seed_same_records_cold_then_warm_one_agent_per_host(
        workdir: Path, cold_then_warm: list[set[int]]) -> None:
    """Reproducible, training overlap included, whether theta_0 is made now (cold cache:
    pretraining on the trial's own hosts, then reseeded) or taken from the cache; and
    pretraining starts no agent of its own: one agent process per host, ever."""
    agents = cold_then_warm
    assert [len(a) for a in agents] == [2, 2]  # 2 hosts: pretraining reused the trial's
    # at the default threads: every core this process may use, OpenMP passive
    numerics = json.loads((workdir / "cold" / "r1" / "run.json").read_text())["numerics"]
    assert numerics["threads"] == len(os.sched_getaffinity(0)), numerics
    assert numerics["compile_act"] is False
    a = (workdir / "cold" / "r1" / "steps.jsonl").read_text()
    b = (workdir / "cold" / "r2" / "steps.jsonl").read_text()
    assert '"wall_time":' in a and a != b
    assert _without_timing(a) == _without_timing(b)


def _assert_same_learner(a: Learner, b: Learner) -> None:
    """Weights, optimiser moments, data, sampler and counters all equal."""
    sa, sb = a.state_dict(), b.state_dict()
    for part in ("policy", "safety", "goal"):
        assert set(sa[part]) == set(sb[part])
        for k in sa[part]:
            va, vb = sa[part][k], sb[part][k]
            if isinstance(va, torch.Tensor):
                assert torch.equal(va, vb), (part, k)
    for part in ("policy_data", "transitions"):
        for k, va in sa[part].items():
            vb = sb[part][k]
            assert torch.equal(va, vb) if isinstance(va, torch.Tensor) else va == vb, (part, k)
    assert torch.equal(sa["sampler"], sb["sampler"])
    assert sa["counters"] == sb["counters"] and a.stats() == b.stats()
    opt_a, opt_b = a.policy_optimizer.state_dict()["state"], b.policy_optimizer.state_dict()[
        "state"]
    assert all(torch.equal(opt_a[k]["exp_avg_sq"], opt_b[k]["exp_avg_sq"]) for k in opt_a)


@pytest.mark.slow
def test_kill_9_then_resume_finishes_with_valid_record(workdir: Path, theta0: Path) -> None:
    # the pretraining cache is warm (``theta0``), so the kill lands in the loop
    assert any((workdir / "runs" / CACHE).glob("*/learner.pt"))
    run = workdir / "runs" / "k"
    proc = subprocess.Popen(
        [sys.executable, "-m", "testbed.cli", "trial", "--config", "small.toml", "--out", "runs",
         "--name", "k", "--steps", "40"],
        cwd=workdir, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        env={**os.environ, "PYTHONPATH": str(ROOT)}, start_new_session=True,
    )
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        p = run / "steps.jsonl"
        if p.exists() and p.read_text().count("\n") >= 10:
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)  # the controller and its host agents, at once
    proc.wait(timeout=30)
    before = read_steps(run / "steps.jsonl")
    assert 10 <= len(before) < 40
    state = json.loads((run / "state.json").read_text())
    # the data store holds at least every checkpointed step (a torn record is not one)
    assert state["t"] + 1 <= RunData.of_run(run).num_steps <= len(before) + 1

    # the learner resume rebuilds (start + the data replayed + the step's weights) is
    # the learner of a run of the same seed that ended at that step, exactly
    rebuilt = resume_learner(RunDir(run).read_config(FleetConfig), RunDir(run), state)
    ref = _cli("trial", "--config", "small.toml", "--out", "runs", "--name", "k-ref",
               "--steps", str(state["t"] + 1), cwd=workdir)
    assert ref.returncode == 0, ref.stderr[-3000:]
    _assert_same_learner(rebuilt, Learner.load(workdir / "runs" / "k-ref" / "learner.pt"))
    saved = torch.load(run / state["learner"], weights_only=True)  # no data in it
    assert "policy_data" not in saved and "transitions" not in saved
    assert saved["data_sizes"] == rebuilt.data_sizes()

    done = _cli("trial", "--resume", str(run), cwd=workdir)
    assert done.returncode == 0, done.stderr[-3000:]
    steps = read_steps(run / "steps.jsonl")
    assert [s["t"] for s in steps] == list(range(40))
    data = RunData.of_run(run)
    assert data.num_steps == 40  # the record and the data agree
    assert [int(t) for t in data.frames()["t"][::4]] == list(range(40))
    assert set(data.frames()["session"][4 * (state["t"] + 1):].tolist()) == {1}
    for s in steps:
        validate_step(s)
    # nothing finished was lost: every checkpointed step is still there, unchanged
    kept = [s for s in before if s["t"] <= state["t"]]
    assert steps[: len(kept)] == kept
    summary = json.loads((run / "summary.json").read_text())
    assert summary == {**summary, **summarize(steps, algorithm="cur", num_humans=2,
                                              num_robots=4)}
    # the first session's code and hosts are kept; the resumed session says its own
    meta = json.loads((run / "run.json").read_text())
    _assert_code_and_hosts(meta, run)
    (code,), (hosts,) = meta["resumed_code"], meta["resumed_hosts"]
    assert code["session"] == hosts["session"] == 1 == len(meta["resumed"])
    assert code["code"]["commit"] == meta["code"]["commit"]
    assert hosts["hosts"].keys() == meta["hosts"].keys()


@pytest.mark.slow
def test_protocol_runs_to_its_report_and_evaluate_uses_the_trained_policy(
        workdir: Path, theta0: Path) -> None:
    proto = {
        "name": "mini",
        "trials": 2,
        "algorithms": ["bc", "cur"],
        "steps": 6,
        "seeds": [5, 6],
        "out": "proto",
        "evaluate_steps": 4,
        "fleet": SMALL,
    }
    (workdir / "mini.toml").write_text(tomli_w.dumps(proto))
    proc = _cli("protocol", "mini.toml", "--yes", cwd=workdir)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = workdir / "proto"
    runs = sorted(p.name for p in out.iterdir() if (p / "steps.jsonl").exists())
    assert runs == ["bc-t0", "bc-t1", "cur-t0", "cur-t1", "eval-bc-t0", "eval-bc-t1",
                    "eval-cur-t0", "eval-cur-t1", "eval-expert-t0", "eval-expert-t1"]
    expert = read_steps(out / "eval-expert-t0" / "steps.jsonl")
    assert len(expert) == 4 and all(
        r["mode"] in ("autonomous", "reset", "idle") and r["uncertainty"] == 0.0
        for s in expert for r in s["robots"])
    # the paper's evaluation: each final policy alone, resets only, named by its run
    for k in range(2):
        ev = out / f"eval-cur-t{k}"
        source = json.loads((ev / "run.json").read_text())["evaluates"]
        assert (workdir / source.pop("policy")).resolve() == (
            out / f"cur-t{k}" / "learner.pt").resolve()
        assert source == {"run": f"cur-t{k}", "algorithm": "cur"}
        steps = read_steps(ev / "steps.jsonl")
        assert len(steps) == 4
        assert all(r["mode"] in ("autonomous", "reset", "idle")
                   for s in steps for r in s["robots"])
    md = (out / "report.md").read_text()
    learning, _, evaluation = md.partition("Evaluation (the paper's 8.3.4")
    assert "| eval:bc | 2 |" in evaluation and "| eval:cur | 2 |" in evaluation
    assert "| eval:expert | 2 |" in evaluation
    assert "eval" not in learning
    table = learning.split("\n\n")[0]  # the first table: mean +- std
    rows = [ln for ln in table.splitlines() if ln.startswith(("| bc ", "| cur "))]
    assert len(rows) == 2 and all("| 2 |" in r for r in rows)
    parts = learning.partition("ROHE and its parts")[2].split("\n\n")[1]
    assert len([ln for ln in parts.splitlines() if ln.startswith(("| bc ", "| cur "))]) == 2
    # the report's new tables: bc paired against cur over the 2 trials, the humans
    assert "Paired against cur (learning)" in learning and "| bc | successes |" in learning
    assert "The humans (per algorithm, summed over trials)" in learning
    assert (out / "report.html").read_text().count("<table>") >= 8
    csv_lines = (out / "report.csv").read_text().splitlines()
    assert csv_lines[0].startswith("algorithm,trials,successes_mean,successes_std")
    png = (out / "curves.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    # failure prediction (issue 36): every signal the runs computed, the others named
    cur_rows = read_steps(out / "cur-t0" / "steps.jsonl")
    assert all(set(r["monitor"]) == {"novelty", "ood"} for s in cur_rows for r in s["robots"]
               if r["mode"] != "fault")
    auc = md.partition("Failure prediction, AUROC")[2].split("\n\n")[1]
    cur_signals = {ln.split(" | ")[1] for ln in auc.splitlines() if ln.startswith("| cur |")}
    bc_signals = {ln.split(" | ")[1] for ln in auc.splitlines() if ln.startswith("| bc |")}
    # ood and ood_u too, unless a run's ood was 0 throughout (named, not scored). The
    # failure head is scored only on runs whose theta_0 (its weights' hash) it never saw:
    # every trial here pretrains from PRETRAIN_SEED, so cur's runs share one theta_0 and
    # bc's another only by their critics (issue 45): which runs it scores is
    # test_monitor_runs.py's to check, not this protocol's
    assert {"uncertainty", "risk", "novelty"} <= cur_signals
    assert {"uncertainty", "novelty"} <= bc_signals and "risk" not in bc_signals
    assert "bc: not scored: goal_risk: its critic did not run" in md
    assert "risk: its critic did not run (bc reads no risk" in md
    assert "The conformal alarms replayed: false alarms per untouched successful" in md
    # BC gives humans hard resets only: it never teleoperates
    for s in read_steps(out / "bc-t0" / "steps.jsonl"):
        assert all(r["mode"] != "teleop" for r in s["robots"])

    ev = _cli("evaluate", "--config", "small.toml", "--policy", str(out / "cur-t0" / "learner.pt"),
              "--steps", "5", "--out", "evals", "--name", "e", cwd=workdir)
    assert ev.returncode == 0, ev.stderr[-3000:]
    steps = read_steps(workdir / "evals" / "e" / "steps.jsonl")
    assert len(steps) == 5
    assert all(r["mode"] in ("autonomous", "reset", "idle") for s in steps for r in s["robots"])

    meta = json.loads((workdir / "evals" / "e" / "run.json").read_text())
    assert meta["evaluates"] == {"policy": str(out / "cur-t0" / "learner.pt"),
                                 "run": "cur-t0", "algorithm": "cur"}
    summary = json.loads((workdir / "evals" / "e" / "summary.json").read_text())
    assert summary["algorithm"] == "eval:cur"

    rep = _cli("report", str(out), str(workdir / "evals"), "--out", "both", cwd=workdir)
    assert rep.returncode == 0, rep.stderr[-3000:]
    md = (workdir / "both" / "report.md").read_text()
    # the evaluation has its own row: the training rows still hold their 2 trials each
    assert "| eval:cur | 3 |" in md and "| bc | 2 |" in md and "| cur | 2 |" in md


def test_check_preflights_every_arm_and_writes_a_mosaic(workdir: Path) -> None:
    proc = _cli("check", "--config", "small.toml", "--mosaic", "m.png", cwd=workdir)
    assert proc.returncode == 0, proc.stderr[-3000:]
    ok_lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("ok ")]
    assert len(ok_lines) == 4
    import cv2

    from testbed.lab.preflight import MOSAIC_LABEL_H, mosaic_size

    img = cv2.imread(str(workdir / "m.png"))
    # 4 arms in a row, each 64x64 crop at x4 under its robot's name strip
    assert img is not None and img.shape == (*mosaic_size(4), 3)
    assert img.shape[0] == MOSAIC_LABEL_H + 256 and img.shape[1] >= 1024
