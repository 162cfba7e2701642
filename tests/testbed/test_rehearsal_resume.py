"""``testbed rehearse`` killed with SIGKILL mid-run, then run again: it goes on.

The operator's PC can die in the middle of a lab's day; the same command run again must
continue where it stopped (issue 35, item 8): the twins, sshds and agents of the killed
process gone with it (none left holding a port or a robot lock), the calibration kept,
the run in progress resumed from its checkpoint, and every step, frame, truth row and
fault recorded once. Everything is real, as in test_rehearsal.py (two hardware twins
behind two sshds, the agents on ABB's client); the learning sizes are the tests'. The
first session starts from the run's one calibration (kept_calibration.py, checked in
test_rehearsal.py) as a rehearsal run again does: what this test proves of calibration
is that the session after the kill keeps it, not that it can be made.
``benchmarks/bench_rehearsal_day.py`` does the same to the whole day.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from kept_calibration import kept_calibration, start_from
from lab_fixtures import tiny_protocol

from drivers.testing.sshd import sshd_available
from testbed.lab.fault_report import read_faults
from testbed.lab.hardware_twin import PIDS_FILE, _proc_start
from testbed.lab.twin_truth import truth_agreement
from testbed.records.steps import read_steps
from testbed.records.store import MODES, RunData

pytestmark = [
    pytest.mark.slow,
    pytest.mark.ssh,
    pytest.mark.timeout(1200),  # two rehearsal sessions (and the run's one calibration)
    pytest.mark.skipif(not sshd_available(), reason="needs OpenSSH sshd (openssh-server)"),
]

ROOT = Path(__file__).resolve().parents[2]
STEPS = 14
KILL_AT = 6


def _alive(out: Path) -> list[int]:
    """The lab processes of ``out`` (``lab/pids.json``) still running as themselves."""
    try:
        entries = json.loads((out / "lab" / PIDS_FILE).read_text())
    except (OSError, ValueError):
        return []
    return [int(e["pid"]) for e in entries if _proc_start(int(e["pid"])) == e["start"]]


def _rows(run: Path) -> int:
    path = run / "steps.jsonl"
    return path.read_bytes().count(b"\n") if path.exists() else 0


def _check_run(run: Path, killed_at: int | None) -> None:
    """Every step, frame and truth row of ``run`` once; its faults once, each cleared;
    perception against the truth as in the faults test."""
    rows = read_steps(run / "steps.jsonl")
    assert [r["t"] for r in rows] == list(range(STEPS))  # every step once
    robots = [x["robot"] for x in rows[0]["robots"]]
    frames = RunData.of_run(run).frames()
    assert [(int(f["t"]), int(f["arm"])) for f in frames] == [
        (t, a) for t in range(STEPS) for a in range(len(robots))]  # every frame once
    for f in frames:
        x = rows[int(f["t"])]["robots"][int(f["arm"])]
        assert MODES[int(f["mode"])] == x["mode"]
        assert int(f["action"]) == (-1 if x.get("action") is None else int(x["action"]))
    if killed_at is not None:
        assert {int(f["session"]) for f in frames if int(f["t"]) >= killed_at} == {1}
    truth = [(r["t"], r["robot"]) for r in map(
        json.loads, (run / "twin_truth.jsonl").read_text().splitlines())]
    assert sorted(truth) == [(t, r) for t in range(STEPS) for r in sorted(robots)]
    faults = read_faults(run)  # 2 kinds fit in 14 steps; each once, each cleared
    kinds = [f["kind"] for f in faults]
    assert len(kinds) == 2 and len(set(kinds)) == 2, faults
    assert all(f["actions"] and "(not recorded)" not in f["actions"] for f in faults)
    a = truth_agreement(run)
    assert all(d["borderline"] for d in a["disagreements"]), a["disagreements"]
    assert a["rate"] >= 0.95, a


def test_a_rehearsal_killed_mid_run_goes_on_when_run_again_and_keeps_every_row_once(
        request: pytest.FixtureRequest, tmp_path: Path) -> None:
    out = tmp_path / "rehearsal"
    protocol = tiny_protocol(tmp_path)
    kept = kept_calibration(request, protocol)
    start_from(kept, out)
    cmd = [sys.executable, "-m", "testbed.cli", "rehearse", str(protocol),
           "--steps", str(STEPS), "--algorithms", "bc,fleet-ed", "--faults", "--out",
           str(out), "--camera-fps", "30"]
    first_log = tmp_path / "first.log"
    with open(first_log, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 600  # theta_0 is pretrained first: minutes under load
        while (max((_rows(r) for r in out.glob("*-t0")), default=0) < KILL_AT
               and proc.poll() is None and time.monotonic() < deadline):
            time.sleep(0.05)
        assert proc.poll() is None, first_log.read_text()[-3000:]
        os.kill(proc.pid, signal.SIGKILL)  # the operator's process alone
        proc.wait()
    finally:
        if proc.poll() is None:
            proc.kill()
    (run,) = [r for r in out.glob("*-t0") if _rows(r)]  # the run in progress
    killed_at = _rows(run)
    assert killed_at >= KILL_AT, first_log.read_text()[-3000:]
    gone = time.monotonic() + 15
    while _alive(out) and time.monotonic() < gone:
        time.sleep(0.1)
    assert not _alive(out), "the killed rehearsal's twins and sshds still run"
    assert json.loads((run / "run.json").read_text())["status"] == "running"
    for f in sorted((kept.lab / "calib").glob("*.json")):  # the first session kept them too
        assert (out / "lab" / "calib" / f.name).read_bytes() == f.read_bytes(), f.name

    again = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=240,
                           stdin=subprocess.DEVNULL)
    said = again.stdout + again.stderr
    assert again.returncode == 0, said[-3000:]
    assert "calibration: every arm's from the last session" in said  # not calibrated again
    assert "calibrate yumi-a/left" not in said
    assert "collect:" not in said  # the next run starts from the first session's theta_0
    assert not _alive(out)
    meta = json.loads((run / "run.json").read_text())
    assert meta["status"] == "complete" and len(meta["resumed"]) == 1
    _check_run(run, killed_at)
    (other,) = [r for r in out.glob("*-t0") if r != run]
    assert "resumed" not in json.loads((other / "run.json").read_text())
    _check_run(other, None)
