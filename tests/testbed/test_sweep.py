"""Sweeps (issue 12, item 4): a grid over config fields x seeds expands to the right
runs, every value is validated up front, and the report draws one line per point."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import tomli_w

from testbed.cli import main
from testbed.core.config import ConfigError
from testbed.experiments.sweep import load_sweep
from testbed.records.steps import RunWriter, read_steps
from testbed.results.report import write_report

ROOT = Path(__file__).resolve().parents[2]


def _write(tmp: Path, **over: object) -> Path:
    data: dict[str, object] = {"name": "s", "algorithm": "cur", "steps": 5, "seeds": [0, 1],
                               "grid": {"humans.count": [1, 2], "algorithm.t_T": [3, 5]},
                               "fleet": {"humans": {"count": 2}}}
    data.update(over)
    path = tmp / "sweep.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def test_a_grid_expands_to_every_point_times_every_seed(tmp_path: Path) -> None:
    sweep = load_sweep(_write(tmp_path))
    runs = sweep.runs()
    assert [r.name for r in runs] == [
        f"humans.count-{m}_algorithm.t_T-{t}-s{s}" for m in (1, 2) for t in (3, 5)
        for s in (0, 1)]
    for r in runs:
        assert r.fleet.humans.count == r.point.values["humans.count"]
        assert r.fleet.algorithm.t_T == r.point.values["algorithm.t_T"]
        assert r.fleet.algorithm.t_R == sweep.fleet.algorithm.t_R  # the rest as given
        assert r.algorithm == "cur"
    assert sweep.folder == Path("runs/sweep-s")
    ablations = load_sweep(_write(tmp_path, grid={"algorithm": ["cur", "cur-i", "cu"]}))
    assert [(r.algorithm, r.seed) for r in ablations.runs()] == [
        (a, s) for a in ("cur", "cur-i", "cu") for s in (0, 1)]
    # a field the base fleet leaves unset can still be swept
    opt = load_sweep(_write(tmp_path, grid={"learning.critic_pretrain_steps": [5, 10]}))
    assert [r.fleet.learning.critic_pretrain_steps for r in opt.runs()] == [5, 5, 10, 10]


@pytest.mark.parametrize(("grid", "where"), [
    ({"humans.cont": [1]}, "grid.humans.cont: no such config field"),
    ({"nope.t_T": [1]}, "grid.nope.t_T: no such config field"),
    ({"humans.count": [-1]}, "humans.count"),
    ({"algorithm.t_T": ["x"]}, "algorithm.t_T"),
    ({"algorithm": ["cur", "best"]}, "unknown algorithm 'best'"),
    ({"humans.count": []}, "grid.humans.count: give at least one value"),
])
def test_a_bad_grid_exits_2_with_one_line_naming_the_field(
        tmp_path: Path, grid: dict[str, list[object]], where: str,
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """The CLI's own ``main`` in this process (``python -m testbed.cli`` is
    ``SystemExit(main())``; test_cli_errors.py runs the verbs so too): the exit status
    and stderr are the same, without a Python and an import of the product per case."""
    path = _write(tmp_path, grid=grid)
    with pytest.raises(ConfigError, match=where.replace(".", r"\.").replace("(", r"\(")):
        load_sweep(path)
    monkeypatch.chdir(tmp_path)
    handlers = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    try:
        code = main(["sweep", str(path)])
    finally:  # main installs the CLI's Ctrl-C handlers: give pytest its own back
        signal.signal(signal.SIGINT, handlers[0])
        signal.signal(signal.SIGTERM, handlers[1])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert where.split(":")[0] in err and "Traceback" not in err


def _run(folder: Path, point: str, successes: list[bool]) -> None:
    folder.mkdir(parents=True)
    with RunWriter(folder) as w:
        for t, ok in enumerate(successes):
            w.write_step({"t": t, "robots": [{
                "robot": "h/a", "mode": "autonomous", "human": None, "action": 1,
                "success": ok, "violation": False, "uncertainty": 0.1, "risk": 0.0,
                "key": [0.0]}]})
    (folder / "run.json").write_text(json.dumps({
        "options": {"algorithm": "cur"}, "status": "complete",
        "sweep": {"name": "s", "point": point, "values": {}, "seed": 0}}))


def test_the_report_groups_a_sweeps_runs_by_point_in_file_order(tmp_path: Path) -> None:
    _run(tmp_path / "m-2-s0", "m-2", [True, True, False])
    _run(tmp_path / "m-2-s1", "m-2", [True, False, False])
    _run(tmp_path / "m-1-s0", "m-1", [False, False, False])
    report = write_report([tmp_path], tmp_path)
    lines = report.markdown.splitlines()
    assert lines[0].startswith("| point | trials | successes")
    rows = {line.split(" | ")[0].strip("| "): line for line in lines[2:4]}
    assert set(rows) == {"m-1", "m-2"}
    assert "| 2 | 1.5 ± 0.5 |" in rows["m-2"] and "| 1 | 0.0 ± 0.0 |" in rows["m-1"]
    assert (tmp_path / "curves.png").stat().st_size > 10_000
    assert len(read_steps(tmp_path / "m-2-s0" / "steps.jsonl")) == 3


@pytest.mark.slow
def test_a_small_sweep_runs_to_its_report(tmp_path: Path) -> None:
    path = _write(tmp_path, steps=3, seeds=[0], grid={"humans.count": [1, 2]},
                  out=str(tmp_path / "out"),
                  fleet={"learning": {"ensemble_size": 2, "batch_size": 16, "demos": 30,
                                      "critic_transitions": 20, "pretrain_steps": 4}})
    cli = subprocess.run([sys.executable, "-m", "testbed.cli", "sweep", str(path)],
                         capture_output=True, text=True, cwd=tmp_path, timeout=600,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert cli.returncode == 0, cli.stderr[-3000:]
    out = tmp_path / "out"
    for name, m in (("humans.count-1-s0", 1), ("humans.count-2-s0", 2)):
        meta = json.loads((out / name / "run.json").read_text())
        assert meta["sweep"]["values"] == {"humans.count": m} and meta["status"] == "complete"
        assert len(read_steps(out / name / "steps.jsonl")) == 3
    assert "| humans.count-1 | 1 |" in cli.stdout and "| humans.count-2 | 1 |" in cli.stdout
    assert (out / "curves.png").exists()
    again = subprocess.run([sys.executable, "-m", "testbed.cli", "sweep", str(path)],
                           capture_output=True, text=True, cwd=tmp_path, timeout=120,
                           env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert again.returncode == 0 and again.stdout == cli.stdout  # finished runs skipped
    # policy: a second sweep of 4 arms starts every run from the first run's theta_0
    # (its data included): no pretraining of its own, and the same resolved threshold
    start = out / "humans.count-1-s0" / "learner-start.pt"
    held = _write(tmp_path, steps=3, seeds=[0], grid={"humans.count": [1]},
                  out=str(tmp_path / "held"), policy=str(start), fleet={
                      "learning": {"ensemble_size": 2, "batch_size": 16, "demos": 30,
                                   "critic_transitions": 20, "pretrain_steps": 4},
                      "hosts": [{"name": "cell0"}, {"name": "cell1"}]})
    cli = subprocess.run([sys.executable, "-m", "testbed.cli", "sweep", str(held)],
                         capture_output=True, text=True, cwd=tmp_path, timeout=600,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert cli.returncode == 0, cli.stderr[-3000:]
    run = tmp_path / "held" / "humans.count-1-s0"
    assert json.loads((run / "run.json").read_text())["options"]["policy"] == str(start)
    assert not (tmp_path / "held" / ".pretrained").exists()
    assert len({r["robot"] for r in read_steps(run / "steps.jsonl")[0]["robots"]}) == 4


def test_a_sweeps_policy_must_be_a_file(tmp_path: Path) -> None:
    path = _write(tmp_path, policy=str(tmp_path / "none.pt"))
    with pytest.raises(ConfigError, match=r"policy: no such file .*none\.pt.*learner-start"):
        load_sweep(path)
