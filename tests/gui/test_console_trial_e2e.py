"""End to end: ``testbed trial --humans gui`` on the twin, people played by xdotool.

The trial runs in its own process on a private Xvfb; the autopilot reads the console's
state file (``$TESTBED_CONSOLE_STATE``) and answers like two people would: human 0
presses ``w`` (push up, action 0), human 1 clicks face marker 3 (push right), both
press Enter on a hard-reset banner. The records must show exactly those pushes on the
arms each human held, and hard resets that completed (the arm went back to work).
"""

from __future__ import annotations

import os
import subprocess
import sys
from itertools import pairwise
from pathlib import Path

import pytest
import tomli_w

from gui.xdo import Autopilot, Xvfb
from testbed.records.steps import read_steps

ROOT = Path(__file__).resolve().parents[2]
SMALL = {
    # 18 steps: room after a late reset for the arm to go back to work (with 12, a reset
    # answered late under load once left none completed: docs/notes/tests.md)
    "trial": {"steps": 18, "seed": 3},
    # Every arm eligible for teleop: what a console test needs is a teleop, whatever the
    # uncertainty of a policy pretrained on the humans' (timing-dependent) answers.
    "algorithm": {"u_hat": 0.0},
    "learning": {
        "ensemble_size": 2,
        "batch_size": 32,
        "demos": 60,
        "critic_transitions": 40,
        "pretrain_steps": 5,
    },
}
PUSH_OF_HUMAN = {0: 0, 1: 3}


@pytest.mark.slow
@pytest.mark.xvfb
def test_trial_with_console_humans(xvfb: Xvfb, tmp_path: Path) -> None:
    (tmp_path / "small.toml").write_text(tomli_w.dumps(SMALL))
    state = tmp_path / "console.json"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "DISPLAY": xvfb.display,
           "TESTBED_CONSOLE_STATE": str(state)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "testbed.cli", "trial", "--config", "small.toml",
         "--out", "runs", "--name", "gui", "--humans", "gui"],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    with Autopilot(state, xvfb.display,
                   lambda h: ("key", "w") if h == 0 else ("click", PUSH_OF_HUMAN[1])) as pilot:
        try:
            _, err = proc.communicate(timeout=240)
        except subprocess.TimeoutExpired:  # say where it stood, not only that it hung
            proc.kill()
            _, err = proc.communicate(timeout=30)
            console = state.read_text() if state.exists() else "(no state file)"
            pytest.fail(f"the trial did not end in 240 s; the autopilot answered "
                        f"{len(pilot.answers)} prompts ({pilot.retries} again), the last "
                        f"{pilot.answers[-3:]}; console state: {console[-1500:]}; "
                        f"stderr tail:\n{err[-3000:]}")
        finally:
            if proc.poll() is None:
                proc.kill()
    assert proc.returncode == 0, err[-3000:]
    assert {a[2] for a in pilot.answers} >= {"choose", "reset"}

    steps = read_steps(tmp_path / "runs" / "gui" / "steps.jsonl")
    assert len(steps) == SMALL["trial"]["steps"]
    teleop = [r for s in steps for r in s["robots"] if r["mode"] == "teleop"]
    assert teleop, "no arm was teleoperated"
    for row in teleop:
        assert row["action"] == PUSH_OF_HUMAN[row["human"]], row
    completed = 0
    for i, robot in enumerate(steps[0]["robots"]):
        modes = [s["robots"][i]["mode"] for s in steps]
        completed += any(
            a == "reset" and b in ("autonomous", "teleop") for a, b in pairwise(modes)
        )
        assert robot["robot"] == steps[-1]["robots"][i]["robot"]
    assert completed >= 1, "no hard reset was completed by Enter"
