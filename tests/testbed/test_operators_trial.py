"""A real twin trial with ``algorithm.operators = "matched"``: the built-in twin fleet
(2 hosts x 2 arms, agents in their own processes, PyBullet), a small learner, and two
scripted humans who differ (``protocols/twin-operators.toml``'s kind of fleet, more
extreme): "ana" the paper's expert, "bo" of skill 0 who takes a step to start. The run
must finish, its records must validate, its config must say it was matched, and the
report's per-human table must show the estimates beside the profiles; every new teleop
must have gone to a human expected to do at least as well as the policy."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import tomli_w

from testbed.fleet.operators import OperatorModel
from testbed.records.steps import read_steps, validate_step
from testbed.results.report import write_report

ROOT = Path(__file__).resolve().parents[2]

CONFIG = {
    "trial": {"steps": 30, "seed": 4},
    "humans": {"kind": "scripted", "people": [  # bo first: blind would favour him
        {"name": "bo", "skill": 0.0, "latency": 1}, {"name": "ana"}]},
    "algorithm": {"operators": "matched", "t_T": 3, "t_R": 3, "t_I": 0, "u_hat": 0.0},
    "learning": {"ensemble_size": 2, "batch_size": 32, "demos": 60,
                 "critic_transitions": 40, "pretrain_steps": 10},
}


@pytest.mark.slow
def test_a_matched_twin_trial_runs_records_and_reports(tmp_path: Path) -> None:
    (tmp_path / "matched.toml").write_text(tomli_w.dumps(CONFIG))
    proc = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "trial", "--config", "matched.toml",
         "--out", "runs", "--name", "m"],
        cwd=tmp_path, capture_output=True, text=True, timeout=600,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = tmp_path / "runs" / "m"
    assert 'operators = "matched"' in (run / "config.toml").read_text()
    rows = read_steps(run / "steps.jsonl")
    assert [r["t"] for r in rows] == list(range(30))
    for row in rows:
        validate_step(row)
    # The matched rule, checked on the records whatever the learner's last bits on this
    # CPU made the policy do: each new teleop went to a human the model (of the rows
    # before) expected to do at least as well as the policy, and of two new teleops at
    # one step, the arm with the higher key went to the human with the higher gain
    # (blind gives it to bo, the lower index).
    model = OperatorModel(2, 3, 3)
    pairs = 0
    for row in rows:
        gains = model.gains([False])[:, 0]
        new = [r for r in row["robots"] if r["mode"] == "teleop" and r.get("served") == 0]
        for r in new:
            assert gains[r["human"]] >= -1e-9, (row["t"], gains)
        if len(new) == 2 and new[0]["key"] != new[1]["key"] and gains[0] != gains[1]:
            top, other = sorted(new, key=lambda r: tuple(r["key"]), reverse=True)
            assert gains[top["human"]] > gains[other["human"]], (row["t"], gains, new)
            pairs += 1
        model.observe(row)
    assert pairs > 0, "no step tested the pairing"
    bo, ana = model.estimates()
    assert ana.skill > bo.skill and ana.latency_steps < bo.latency_steps, (ana, bo)
    table = next(t for t in write_report([run], tmp_path / "rep").tables
                 if t.key == "humans")
    cells = {r[1]: r for r in table.rows}
    assert cells["ana"][-3].endswith("(1)") and cells["bo"][-3].endswith("(0)")
    assert cells["bo"][-2].endswith("(1)") and cells["bo"][-1].endswith("(4)")
