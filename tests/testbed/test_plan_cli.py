"""``testbed plan`` end to end through the real CLI: its table, CSV, figure and answer on
runs of the real loop (``plan_fakes``), its errors (exit 2, one line naming the
argument), and ``--trials`` handed to the trials planner with its flags.
"""

from __future__ import annotations

import contextlib
import csv
import io
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
from plan_fakes import World, run_world

from testbed.cli import main
from testbed.people.people_config import HumanProfile
from testbed.planning.plan_fit import METRICS

ROBOTS, HUMANS = (4, 6), (1, 2, 3)


@pytest.fixture(scope="module")
def protocol(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("plan-cli") / "protocol"
    people = [HumanProfile(name="ana"), HumanProfile(name="bo", latency=1)]
    for s in (0, 1):
        run_world(root / f"cur-t{s}", World(), arms=4, people=people, steps=120, seed=s)
    return root


@pytest.fixture(scope="module")
def planned(protocol: Path, tmp_path_factory: pytest.TempPathFactory
            ) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("plan-out")
    buf = io.StringIO()  # a module fixture has no capsys
    with contextlib.redirect_stdout(buf):
        code = main(["plan", str(protocol), "--robots", ",".join(map(str, ROBOTS)),
                     "--humans", ",".join(map(str, HUMANS)), "--replicates", "60",
                     "--steps", "150", "--out", str(out)])
    assert code == 0
    return out, buf.getvalue()


def test_the_table_has_every_point_with_intervals(planned: tuple[Path, str]) -> None:
    out, printed = planned
    md = (out / "plan.md").read_text()
    assert md in printed and "## Plan: cur" in md
    assert "Fit: 2 run(s) of cur (cur-t0, cur-t1) at N=4, M=2, up to 120 steps" in md
    for n in ROBOTS:
        for m in HUMANS:
            row = next(line for line in md.splitlines() if line.startswith(f"| {n} | {m} |"))
            assert row.count("[") == len(METRICS), row
    assert "| measured (mean of runs) |" in md and "| predicted |" in md
    assert "| ana |" in md and "| bo |" in md


def test_the_csv_is_every_point_metric_with_its_interval(planned: tuple[Path, str]) -> None:
    out, _ = planned
    with (out / "plan.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["algorithm", "point", "N", "M", "metric", "mean", "low", "high"]
    grid = {(int(r["N"]), int(r["M"])) for r in rows}
    assert {(n, m) for n in ROBOTS for m in HUMANS} <= grid
    assert {(4, 3), (6, 2)} <= grid  # one more person, two more arms, from N=4, M=2
    for r in rows:
        assert float(r["low"]) <= float(r["mean"]) <= float(r["high"]), r
        assert r["point"] == f"N{r['N']}-M{r['M']}" and r["metric"] in METRICS
    assert len(rows) == len(grid) * len(METRICS)


def test_the_figure_and_the_answers(planned: tuple[Path, str]) -> None:
    out, printed = planned
    png = (out / "plan-cur.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    knees = [line for line in printed.splitlines() if line.startswith("- N=")]
    assert [k.split(":")[0] for k in knees] == ["- N=4", "- N=6"]
    assert all("stops paying after M=" in k or "still pays up to M=3" in k for k in knees)
    answer = next(line for line in printed.splitlines()
                  if line.startswith("One more person or two more arms? cur at N=4, M=2: "))
    assert any(c in answer for c in ("two more arms:", "one more person:", "either"))
    assert f"plan: {out / 'plan.md'}, {out / 'plan.csv'}, {out / 'plan-cur.png'}" in printed


def one_line(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    try:
        code = main(argv)
    except SystemExit as exc:
        code = int(exc.code or 0)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize(("extra", "words"), [
    (["--robots", "4,x", "--humans", "1"], "argument --robots: expected a comma-separated "
     "list of positive integers, got '4,x'"),
    (["--robots", "4", "--humans", "0,1"], "argument --humans: expected a comma-separated"),
    (["--robots", "4", "--humans", ""], "argument --humans: expected"),
    (["--humans", "1,2"], "--robots: required"),
    (["--robots", "4"], "--humans: required"),
    (["--robots", "4", "--humans", "1", "--min-gain", "1.5"], "argument --min-gain: "
     "expected a number between 0 and 1"),
    (["--robots", "4", "--humans", "1", "--alpha", "0.1"], "--alpha: only with --trials"),
    (["--robots", "4", "--humans", "1", "--reference", "cur"],
     "--reference: only with --trials"),
    (["--trials", "--metric", "speed"], "argument --metric: invalid choice"),
    (["--robots", "4", "--humans", "1", "--replicates", "0"], "argument --replicates"),
])
def test_bad_arguments_exit_2_naming_the_argument(
        extra: list[str], words: str, protocol: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    assert words in one_line(["plan", str(protocol), *extra], capsys)


def test_bad_folders_exit_2(protocol: Path, tmp_path: Path,
                            capsys: pytest.CaptureFixture[str]) -> None:
    grid = ["--robots", "4", "--humans", "1"]
    line = one_line(["plan", str(tmp_path / "nowhere"), *grid], capsys)
    assert line == f"testbed plan: RUN_OR_PROTOCOL_DIR: no such folder '{tmp_path / 'nowhere'}'"
    assert "no run found" in one_line(["plan", str(tmp_path), *grid], capsys)
    running = tmp_path / "cur-t0"
    running.mkdir()
    (running / "steps.jsonl").write_text((protocol / "cur-t0" / "steps.jsonl").read_text())
    (running / "run.json").write_text('{"status": "running"}')
    line = one_line(["plan", str(tmp_path), *grid], capsys)
    assert "RUN_OR_PROTOCOL_DIR: no finished run to fit (1 run(s) left out, unfinished" in line
    (tmp_path / "a-file").write_text("")
    line = one_line(["plan", str(protocol), *grid, "--out", str(tmp_path / "a-file")], capsys)
    assert "--out:" in line and "is a file" in line


def test_trials_hands_the_flags_to_the_trials_planner(
        protocol: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    calls: list[tuple[list[Path], dict[str, Any]]] = []
    fake = ModuleType("testbed.planning.plan_trials")

    def plan_trials(dirs: list[Path], **kwargs: Any) -> str:
        calls.append((dirs, kwargs))
        return "TRIALS TABLE"

    fake.plan_trials = plan_trials  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "testbed.planning.plan_trials", fake)
    assert main(["plan", str(protocol), "--trials"]) == 0
    assert capsys.readouterr().out.strip() == "TRIALS TABLE"
    assert calls[-1] == ([protocol], {"reference": None, "metric": "rohe", "alpha": 0.05,
                                      "power": 0.8, "max_trials": 30})
    assert main(["plan", str(protocol), "--trials", "--reference", "random", "--metric",
                 "successes", "--alpha", "0.1", "--power", "0.9", "--max-trials", "12"]) == 0
    assert calls[-1][1] == {"reference": "random", "metric": "successes", "alpha": 0.1,
                            "power": 0.9, "max_trials": 12}


def test_trials_without_the_trials_planner_is_one_line(
        protocol: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setitem(sys.modules, "testbed.planning.plan_trials", None)
    line = one_line(["plan", str(protocol), "--trials"], capsys)
    assert line.startswith("testbed plan: --trials: this build has no trials planner")


def test_against_puts_a_measured_sweep_beside_the_plan(
        protocol: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The same world measured at N=4, M=1 and N=6, M=3 (2 runs each, 120 steps), one
    point outside the grid and one of another length: per point and metric the measured
    mean and the interval, the count inside, and a note for each point left out."""
    sweep = tmp_path / "sweep"
    people = [HumanProfile(name="ana"), HumanProfile(name="bo", latency=1)]
    for n, m, steps in ((4, 1, 120), (6, 3, 120), (8, 1, 120), (4, 2, 60)):
        for s in (0, 1):
            run_world(sweep / f"n{n}m{m}-{steps}-s{s}", World(), arms=n, steps=steps,
                      seed=10 + s, people=[people[h % 2] for h in range(m)])
    out = tmp_path / "out"
    assert main(["plan", str(protocol), "--robots", "4,6", "--humans", "1,2,3",
                 "--replicates", "100", "--runs", "2", "--out", str(out),
                 "--against", str(sweep)]) == 0
    printed = capsys.readouterr().out
    md = (out / "plan.md").read_text()
    assert md in printed and "## Predicted and measured: cur" in md
    assert "--against: cur N=8, M=1 left out: not in the plan's grid" in md
    assert "--against: cur N=4, M=2 left out: its runs have 60 steps, the plan 120" in md
    with (out / "plan-check.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {(r["N"], r["M"], r["runs"]) for r in rows} == {("4", "1", "2"), ("6", "3", "2")}
    assert len(rows) == 2 * len(METRICS)
    for r in rows:  # the measured mean and the plan's interval for that point and metric
        assert r["inside"] == str(int(float(r["low"]) <= float(r["measured"])
                                      <= float(r["high"]))), r
    inside = {k: sum(int(r["inside"]) for r in rows if r["metric"] == k) for k in METRICS}
    assert inside["human_actions"] >= 1 and inside["idle_time"] >= 1  # the true world
    counts = next(line for line in md.splitlines() if line.startswith("Inside the interval"))
    assert counts.startswith("Inside the interval, of 2 point(s): successes "
                             f"{inside['successes']},")
    row = next(line for line in md.splitlines() if line.startswith("| 4 | 1 | 2 |"))
    assert row.count("[") == len(METRICS) and ("in" in row or "OUT" in row)
    line = one_line(["plan", str(protocol), "--trials", "--against", str(sweep)], capsys)
    assert "--against: only without --trials" in line


def test_on_site_plans_the_first_k_in_the_room_and_fewer_resets_served(
        protocol: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--on-site 1``: of 3 planned people only the first does hard resets, which the
    plan says, and which costs the fleet: more idle time than with all 3 in the room."""
    def plan(out: Path, *extra: str) -> dict[str, float]:
        assert main(["plan", str(protocol), "--robots", "6", "--humans", "3", "--replicates",
                     "60", "--steps", "150", "--out", str(out), *extra]) == 0
        with (out / "plan.csv").open() as f:
            return {r["metric"]: float(r["mean"]) for r in csv.DictReader(f)
                    if r["point"] == "N6-M3"}

    everyone = plan(tmp_path / "all")
    one = plan(tmp_path / "one", "--on-site", "1")
    md = (tmp_path / "one" / "plan.md").read_text()
    assert "Places: the first 1 of each M on site (teleop and hard resets)" in md
    assert "Places:" not in (tmp_path / "all" / "plan.md").read_text()
    assert one["idle_time"] > everyone["idle_time"], (one, everyone)
    capsys.readouterr()
    assert main(["plan", str(protocol), "--robots", "6", "--humans", "3",
                 "--on-site", "0"]) == 2
    assert capsys.readouterr().err.strip() == (
        "testbed plan: --on-site: 0; at least 1 (a hard reset needs a person in the room "
        "with the arms)")
