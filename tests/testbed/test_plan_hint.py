"""The plan's hint and ``--dry-run`` as a newcomer meets them (the docs review of issue 44).

* The hint ``make it ahead: testbed collect ..., then testbed pretrain ...`` printed by
  ``trial --dry-run`` and ``protocol --dry-run``, run as printed, fills the very cache
  the printing command then reads: a trial (its out folder, ``runs`` by default) and a
  protocol (its own out) keep separate caches, and a protocol file's ``humans`` is not
  the trial's.
* ``--dry-run`` before the lab's setup is done (no key, no known_hosts, no display)
  still prints the plan, and says what it did not check.

Real parts: the CLI in-process, the real twin and real torch at tiny learning sizes,
scripted humans.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from testbed.cli import main
from testbed.experiments import time_plan
from testbed.experiments.pace import GradPace

ROOT = Path(__file__).resolve().parents[2]

PROTOCOL = """name = "p"
trials = 1
algorithms = ["bc", "cur"]
steps = 2
evaluate_steps = 0
out = "proto-out"
humans = "gui"
[fleet.humans]
count = 1
kind = "scripted"
[fleet.learning]
ensemble_size = 2
batch_size = 16
demos = 12
critic_transitions = 6
pretrain_steps = 2
[[fleet.hosts]]
name = "cell0"
"""
HINT = re.compile(r"testbed collect (.+), then testbed pretrain (.+)$", re.M)


def _hint(text: str) -> tuple[list[str], list[str]]:
    found = HINT.search(text)
    assert found is not None, text
    return shlex.split(found.group(1)), shlex.split(found.group(2))


def _run_hint(capsys: pytest.CaptureFixture[str], printed: str) -> None:
    collect, pretrain = _hint(printed)
    assert main(["collect", *collect]) == 0
    assert main(["pretrain", *pretrain]) == 0
    capsys.readouterr()


def test_the_trials_hint_fills_the_cache_the_trial_reads(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``trial --config PROTOCOL`` reads ``runs/.pretrained`` with the [fleet]'s scripted
    humans; collect given the protocol file alone would fill ``proto-out`` with the
    protocol's gui humans. The hint names the folder and the humans, and the trial then
    neither collects nor pretrains."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("TESTBED_PROGRESS", "plain")
    (tmp_path / "p.toml").write_text(PROTOCOL)
    assert main(["trial", "--config", "p.toml", "--dry-run"]) == 0
    printed = capsys.readouterr().out
    collect, pretrain = _hint(printed)
    assert collect == pretrain
    assert collect[collect.index("--runs") + 1] == "runs"
    assert collect[collect.index("--humans") + 1] == "scripted"
    _run_hint(capsys, printed)
    assert not (tmp_path / "proto-out").exists()
    assert main(["trial", "--config", "p.toml", "--dry-run"]) == 0
    again = capsys.readouterr().out
    assert re.search(r"^  theta_0 +1 learner +- +skipped  \(cached: runs/", again, re.M)
    assert "make it ahead" not in again
    assert main(["trial", "--config", "p.toml"]) == 0
    ran = capsys.readouterr()
    assert "trial: started" in ran.err
    for phase in ("collect", "rollout", "pretrain policy", "pretrain critics"):
        assert f"{phase}: started" not in ran.err, phase


def test_the_protocols_hint_fills_the_cache_the_protocol_reads(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``protocol FILE --out DIR``: the hint names DIR; the protocol's own humans are
    collect's default, so none is named. Here the protocol's humans are the scripted
    ones (a twin), and after the hint its plan starts at the runs."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("TESTBED_PROGRESS", "plain")
    (tmp_path / "p.toml").write_text(PROTOCOL.replace('humans = "gui"', 'humans = "scripted"'))
    assert main(["protocol", "p.toml", "--out", "elsewhere", "--dry-run"]) == 0
    printed = capsys.readouterr().out
    collect, _ = _hint(printed)
    assert collect[collect.index("--runs") + 1] == "elsewhere" and "--humans" not in collect
    _run_hint(capsys, printed)
    assert not (tmp_path / "proto-out").exists() and not (tmp_path / "runs").exists()
    assert main(["protocol", "p.toml", "--out", "elsewhere", "--dry-run"]) == 0
    again = capsys.readouterr().out
    assert re.search(r"^  theta_0 +1 learner +- +skipped  \(cached: elsewhere/", again, re.M)


def test_a_dry_run_needs_no_setup_and_says_what_it_left_unchecked(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The shipped physical protocol before anything is set up: an empty HOME (no
    ~/.ssh/fleet_ed25519, no known_hosts), no DISPLAY for its gui humans. Every
    ``--dry-run`` prints its plan and exits 0; the run itself still refuses (exit 2,
    the key named). The gradient rate is given: this test is about the checks."""
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(time_plan, "measure_gradient",
                        lambda lc, critics: GradPace(1.0, 0.5, "given"))
    physical = str(ROOT / "protocols" / "physical.toml")
    for argv in (["protocol", physical], ["trial", "--config", physical],
                 ["collect", "--config", physical], ["pretrain", "--config", physical]):
        assert main([*argv, "--dry-run"]) == 0, argv
        got = capsys.readouterr()
        assert got.out.startswith("Before step 1"), (argv, got.out)
        assert re.search(r"^  collect demonstrations +375 pairs ", got.out, re.M), argv
        last = got.out.rstrip().splitlines()[-1]
        assert last.startswith("  --dry-run: not checked: the files the config names"), argv
        assert "display" in last, argv
        assert got.err == "", argv
    assert not (tmp_path / "runs").exists()
    assert main(["protocol", physical, "--yes"]) == 2
    err = capsys.readouterr().err
    assert "fleet.hosts[0].key_file: no such file" in err and len(err.splitlines()) == 1
