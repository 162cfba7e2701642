"""Ctrl-C during a twin trial: the arms rest and the records close within 5 s.

Why a file of its own: the test asserts a wall-clock bound, so it runs ``alone``
(tests/conftest.py), and a file with an ``alone`` test is scheduled after all others;
beside test_trial.py's minutes of trials it held that whole file back to the end.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import tomli_w
from test_trial import ROOT, SMALL

from testbed.records.steps import read_steps


@pytest.fixture
def workdir(tmp_path: Path) -> Path:
    (tmp_path / "small.toml").write_text(tomli_w.dumps(SMALL))
    return tmp_path


@pytest.mark.alone  # a wall-clock bound (tests/conftest.py)
@pytest.mark.slow
def test_ctrl_c_rests_arms_and_closes_records_within_5s(workdir: Path) -> None:
    run = workdir / "runs" / "c"
    proc = subprocess.Popen(
        [sys.executable, "-m", "testbed.cli", "trial", "--config", "small.toml", "--out", "runs",
         "--name", "c", "--steps", "400"],
        cwd=workdir, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        p = run / "steps.jsonl"
        if p.exists() and p.read_text().count("\n") >= 3:
            break
        time.sleep(0.05)
    t0 = time.monotonic()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=10)
    elapsed = time.monotonic() - t0
    assert elapsed < 5.0, f"exit took {elapsed:.2f} s; stderr tail:\n{err[-2000:]}"
    assert proc.returncode == 130, err[-2000:]
    assert "interrupted" in err
    steps = read_steps(run / "steps.jsonl")  # no torn line: the records were closed
    assert len(steps) >= 3
