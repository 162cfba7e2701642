"""A real twin trial with one person remote (issue 44): the built-in twin fleet (2 hosts
x 2 arms, agents in their own processes, PyBullet), a small learner, two scripted humans:
"ana" remote (teleop only; of skill 0, so her pushes violate), "bo" on site. Before the
trial the operator is told who is where and what each will be given; the records keep
each person's place; every hard reset in the rows is bo's, ana teleoperates, and an arm
whose teleop by ana violated is never hers the step after (not turned into her reset).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from itertools import pairwise
from pathlib import Path

import pytest
import tomli_w

from testbed.records.steps import read_steps, validate_step

ROOT = Path(__file__).resolve().parents[2]

CONFIG = {
    "trial": {"steps": 40, "seed": 5},
    "humans": {"kind": "scripted", "people": [
        {"name": "ana", "where": "remote", "skill": 0.0}, {"name": "bo"}]},
    # every arm eligible for a teleop: ana must have teleops for the test to mean much
    "algorithm": {"t_T": 3, "t_R": 3, "t_I": 0, "u_hat": 0.0},
    "learning": {"ensemble_size": 2, "batch_size": 32, "demos": 60,
                 "critic_transitions": 40, "pretrain_steps": 10},
}


@pytest.mark.slow
def test_a_twin_trial_gives_the_remote_person_no_reset(tmp_path: Path) -> None:
    (tmp_path / "places.toml").write_text(tomli_w.dumps(CONFIG))
    proc = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "trial", "--config", "places.toml",
         "--out", "runs", "--name", "p"],
        cwd=tmp_path, capture_output=True, text=True, timeout=600,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    err = proc.stderr.splitlines()
    assert "people: ana: remote (teleop only)" in err
    assert "people: bo: on site (teleop and hard resets)" in err
    run = tmp_path / "runs" / "p"
    people = json.loads((run / "run.json").read_text())["humans"]["people"]
    assert [(p["name"], p["where"]) for p in people] == [("ana", "remote"), ("bo", "on_site")]
    config = tomllib.loads((run / "config.toml").read_text())
    assert [p["where"] for p in config["humans"]["people"]] == ["remote", "on_site"]

    rows = read_steps(run / "steps.jsonl")
    assert [r["t"] for r in rows] == list(range(40))
    for row in rows:
        validate_step(row)
    arms = [r for row in rows for r in row["robots"]]
    resets = [r for r in arms if r["mode"] == "reset"]
    assert resets, "no hard reset in 40 steps: the test checked nothing"
    assert all(r["human"] == 1 for r in resets), [r for r in resets if r["human"] != 1]
    assert any(r["mode"] == "teleop" and r["human"] == 0 for r in arms), "ana never teleoped"
    converted = 0
    for before, after in pairwise(rows):
        for a, b in zip(before["robots"], after["robots"], strict=True):
            if a["human"] == 0 and a["violation"]:  # ana's teleop push violated
                assert b["human"] != 0, (after["t"], b)
                converted += 1
    assert converted, "ana's pushes never violated: the conversion went untested"
