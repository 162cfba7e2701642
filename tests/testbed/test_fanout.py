"""Trials on Ray (issue 12, item 5): on a local Ray started by the test (2 CPUs), a small
protocol completes with the serial run's records (same thread count), a worker killed
mid-trial does not lose the trial, and physical fleets are refused with one line."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import tomli_w

from testbed.core.config import ConfigError
from testbed.experiments.fanout import check_fanout
from testbed.experiments.protocol import load_protocol
from testbed.records.steps import read_steps

ROOT = Path(__file__).resolve().parents[2]

PROTOCOL = {
    "name": "fan", "trials": 2, "algorithms": ["cur", "random"], "steps": 14,
    "seeds": [0, 1], "evaluate_steps": 4, "humans": "scripted",
    "fleet": {"algorithm": {"random_budget": "match:cur"},
              "learning": {"ensemble_size": 2, "batch_size": 16, "demos": 40,
                           "critic_transitions": 30, "pretrain_steps": 6}},
}


def _cli(*args: str, cwd: Path, threads: int | None = None) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    if threads is not None:
        env["TESTBED_THREADS"] = str(threads)
    return subprocess.Popen([sys.executable, "-m", "testbed.cli", *args], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env)


def _steps(path: Path) -> list[str]:
    """The run's rows without the timing (the one part that differs between runs)."""
    return [json.dumps({k: v for k, v in r.items() if k not in ("wall_time", "duration_s")},
                       sort_keys=True) for r in read_steps(path / "steps.jsonl")]


def test_physical_fleets_and_console_humans_are_refused() -> None:
    physical = load_protocol(ROOT / "protocols" / "physical.toml", check_files=False)
    with pytest.raises(ConfigError, match=r"drives physical arms .* not interchangeable"):
        check_fanout(physical.fleet, "scripted", "protocol 'physical'")
    twin = load_protocol(ROOT / "protocols" / "twin.toml")
    check_fanout(twin.fleet, "scripted", "protocol 'twin'")
    for console in ("gui", "web"):  # a person at a console (OpenCV or browser) stays put
        with pytest.raises(ConfigError, match=f"humans = '{console}'.*only scripted humans"):
            check_fanout(twin.fleet, console, "protocol 'twin'")


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_a_protocol_on_two_ray_workers_matches_the_serial_run_and_survives_a_kill(
        tmp_path: Path) -> None:
    pytest.importorskip("ray")
    (tmp_path / "fan.toml").write_text(tomli_w.dumps(PROTOCOL))
    serial = _cli("protocol", "fan.toml", "--yes", "--out", "serial", cwd=tmp_path, threads=1)
    _, err = serial.communicate(timeout=600)
    assert serial.returncode == 0, err[-3000:]

    fan = _cli("protocol", "fan.toml", "--out", "fan", "--workers", "2", cwd=tmp_path)
    victim = tmp_path / "fan" / "cur-t1"
    deadline = time.monotonic() + 400
    killed = None
    while time.monotonic() < deadline and fan.poll() is None:
        steps = victim / "steps.jsonl"
        if steps.exists() and steps.read_text().count("\n") >= 5:
            killed = json.loads((victim / "run.json").read_text())["worker"]["pid"]
            os.kill(killed, signal.SIGKILL)  # the Ray worker running cur-t1
            break
        time.sleep(0.1)
    assert killed is not None, "cur-t1 never reached step 5 on a worker"
    _, err = fan.communicate(timeout=600)
    assert fan.returncode == 0, err[-3000:]

    # the killed trial was not lost: retried on a worker, resumed from its checkpoint
    meta = json.loads((victim / "run.json").read_text())
    assert meta["status"] == "complete" and meta.get("resumed")
    assert [r["t"] for r in read_steps(victim / "steps.jsonl")] == list(range(14))
    # every run the kill did not touch has the serial run's records, step for step
    untouched = ["cur-t0", "random-t0", "eval-cur-t0", "eval-random-t0", "eval-expert-t0",
                 "eval-expert-t1"]
    for name in untouched:
        assert _steps(tmp_path / "fan" / name) == _steps(tmp_path / "serial" / name), name
    workers = {json.loads((tmp_path / "fan" / n / "run.json").read_text())["worker"]["pid"]
               for n in ("cur-t0", "cur-t1", "random-t0", "random-t1")}
    assert len(workers) >= 2  # the runs were spread over more than one worker process
    report = (tmp_path / "fan" / "report.md").read_text()
    assert "| cur | 2 |" in report and "| eval:cur | 2 |" in report


SEQUENTIAL = {
    "name": "seqfan", "trials": 2, "algorithms": ["bc", "random"], "steps": 4,
    "seeds": [0, 1], "evaluate_steps": 2, "evaluate_expert": False, "humans": "scripted",
    "until": {"reference": "bc", "metric": "human_actions", "max_trials": 8},
    "fleet": {"hosts": [{"name": "cell0"}], "humans": {"count": 1},
              "algorithm": {"random_budget": 1.0},
              "learning": {"ensemble_size": 2, "batch_size": 16, "demos": 16,
                           "critic_transitions": 8, "pretrain_steps": 4}},
}


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_until_on_ray_workers_stops_after_the_serial_runs_trial(tmp_path: Path) -> None:
    """``until`` fanned out: the first trials at once, then one at a time, the same
    decision after the same trial as the serial loop, no trial run past it, and every
    finished trial evaluated."""
    pytest.importorskip("ray")
    from testbed.results.sequential import RECORD

    (tmp_path / "seq.toml").write_text(tomli_w.dumps(SEQUENTIAL))
    serial = _cli("protocol", "seq.toml", "--yes", "--out", "serial", cwd=tmp_path, threads=1)
    _, err = serial.communicate(timeout=600)
    assert serial.returncode == 0, err[-3000:]
    fan = _cli("protocol", "seq.toml", "--out", "fan", "--workers", "2", cwd=tmp_path)
    out, err = fan.communicate(timeout=600)
    assert fan.returncode == 0, err[-3000:]

    decided = json.loads((tmp_path / "serial" / RECORD).read_text())
    assert decided["stop"] and 2 < decided["trials_done"] < 8  # it went on, then stopped
    assert json.loads((tmp_path / "fan" / RECORD).read_text()) == decided
    done = decided["trials_done"]
    runs = sorted(p.name for p in (tmp_path / "fan").glob("*-t*"))
    assert runs == sorted(p.name for p in (tmp_path / "serial").glob("*-t*"))
    assert runs == sorted(f"{e}{a}-t{k}" for e in ("", "eval-") for a in ("bc", "random")
                          for k in range(done))
    assert f"stops after {done} trial(s)" in err
    assert "Sequential test: each algorithm against bc on human_actions" in out
