"""The report's per-human table: each human's estimates (what the fleet's own model said
at the end of each run) beside the scripted profile they came from."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import pytest

from testbed.fleet.operators import OperatorModel
from testbed.records.steps import RunWriter
from testbed.results.report import write_report
from testbed.results.report_humans import Profile, estimate_humans, scripted_profiles

PEOPLE = ('[[humans.people]]\nname = "ana"\n\n'
          '[[humans.people]]\nname = "bo"\nskill = 0.5\nlatency = 2\n')


def _rows(k: int) -> list[dict[str, Any]]:
    """Arm 0: ana's teleops (first push at once, a success in 2); arm 1: bo's (first
    push 2 steps after the assignment, a success in 6, and resets of 7 steps); arm 2
    the policy's pushes."""
    rows = []
    for t in range(60):
        served = t % 3
        ana = {"robot": "c/0", "mode": "teleop", "human": 0, "action": 1,
               "success": (t + k) % 2 == 0, "violation": False, "served": served,
               **({"first": {"steps": 0, "s": None}} if served == 0 else {})}
        if t % 10 < 7:
            bo = {"robot": "c/1", "mode": "reset", "human": 1, "action": None,
                  "success": False, "violation": False, "served": t % 10,
                  **({"first": {"steps": 6, "s": None}} if t % 10 == 6 else {})}
        else:
            bo = {"robot": "c/1", "mode": "teleop", "human": 1,
                  "action": None if t % 10 < 9 else 2, "success": t % 30 == 9,
                  "violation": False, "served": t % 10 - 7,
                  **({"first": {"steps": 2, "s": None}} if t % 10 == 9 else {})}
        policy = {"robot": "c/2", "mode": "autonomous", "human": None, "action": 0,
                  "success": t % 8 == 0, "violation": False}
        for arm in (ana, bo, policy):
            arm |= {"uncertainty": 0.1, "risk": 0.0, "key": [0.0]}
        rows.append({"t": t, "robots": [ana, bo, policy]})
    return rows


def _runs(root: Path, kind: str = "scripted") -> None:
    for k in range(2):
        folder = root / f"cur-t{k}"
        folder.mkdir(parents=True)
        with RunWriter(folder) as w:
            for row in _rows(k):
                w.write_step(row)
        (folder / "run.json").write_text(json.dumps(
            {"options": {"algorithm": "cur", "seed": k, "steps": 60}, "status": "complete",
             "protocol": {"name": "p", "trial": k, "position": 0, "order": ["cur"]}}))
        (folder / "config.toml").write_text(
            f'[humans]\ncount = 2\nkind = "{kind}"\n{PEOPLE}\n'
            "[algorithm]\nt_T = 3\nt_R = 5\nt_I = 10\nu_hat = 0.05\nr_hat = 0.5\n"
            'operators = "matched"\n')


def test_the_humans_table_shows_each_estimate_beside_its_profile(tmp_path: Path) -> None:
    _runs(tmp_path)
    rep = write_report([tmp_path], tmp_path / "rep")
    table = next(t for t in rep.tables if t.key == "humans")
    assert table.header[-3:] == ["skill est. (profile)", "latency est. (profile)",
                                 "reset est. (profile)"]
    rows = {r[1]: r for r in table.rows}
    # the model fed each run's rows, averaged over the two runs
    ests = []
    for k in range(2):
        model = OperatorModel(2, 3, 5)
        model.observe_all(_rows(k))
        ests.append(model.estimates())
    skill = [(ests[0][h].skill + ests[1][h].skill) / 2 for h in (0, 1)]
    assert rows["ana"][-3] == f"{skill[0]:.3f} (1)"
    assert rows["bo"][-3] == f"{skill[1]:.3f} (0.5)"
    assert skill[0] > skill[1]  # the order of the estimates is the profiles'
    ana_lat, bo_lat = (float(rows[n][-2].split()[0]) for n in ("ana", "bo"))
    assert rows["ana"][-2].endswith("(0)") and rows["bo"][-2].endswith("(2)")
    assert ana_lat < 0.5 < 1.5 < bo_lat < 2.0  # latency 2, shrunk a little to the pool
    assert rows["bo"][-1] == f"{(ests[0][1].reset_steps + ests[1][1].reset_steps) / 2:.2f} (7)"
    pooled = []
    for k in range(2):  # ana never reset: she reads as the pool (bo's 7s and t_R's 5)
        model = OperatorModel(2, 3, 5)
        model.observe_all(_rows(k))
        pooled.append(model.pooled().reset_steps)
    assert rows["ana"][-1] == f"{sum(pooled) / 2:.2f} (5)"
    assert 5.0 < sum(pooled) / 2 < 7.0
    assert any(n.startswith("est.: what the fleet's own model") for n in table.notes)
    with (tmp_path / "rep" / "report-humans.csv").open() as f:
        got = {r["human"]: r for r in csv.DictReader(f)}
    assert float(got["bo"]["skill_estimate"]) == pytest.approx(skill[1], abs=1e-5)
    assert (got["bo"]["skill_profile"], got["bo"]["latency_profile"],
            got["bo"]["reset_profile"]) == ("0.5", "2", "7")


def test_people_at_a_console_have_estimates_and_no_profile(tmp_path: Path) -> None:
    _runs(tmp_path, kind="web")
    table = next(t for t in write_report([tmp_path], tmp_path / "rep").tables
                 if t.key == "humans")
    for row in table.rows:
        assert all("(" not in cell for cell in row[-3:]), row
        assert float(row[-3]) > 0


def test_profiles_and_estimates_from_a_runs_config() -> None:
    humans = {"kind": "scripted", "people": [{"name": "ana"},
                                             {"name": "bo", "skill": 0.6, "latency": 2}]}
    assert scripted_profiles(humans, 3, {"t_R": 4}) == [
        Profile(1.0, 0, 4), Profile(0.6, 2, 6), Profile(1.0, 0, 4)]
    assert scripted_profiles({"kind": "gui"}, 2, {}) == [None, None]
    est = estimate_humans(_rows(0), 2, {"t_T": 3, "t_R": 5})
    assert [e.human for e in est] == [0, 1] and est[0].pushes == 60


def test_the_report_names_each_human_as_the_run_recorded_them(tmp_path: Path) -> None:
    """A run's people have one home, its run.json: the report reads their names there,
    not from the config.toml beside it (here naming no one); a person left unnamed is
    the index's default name."""
    _runs(tmp_path)
    for k in range(2):
        folder = tmp_path / f"cur-t{k}"
        meta = json.loads((folder / "run.json").read_text())
        meta["humans"] = {"people": [{"name": "carla"}, {"name": "human1"}]}
        (folder / "run.json").write_text(json.dumps(meta))
        cfg = (folder / "config.toml").read_text().replace(PEOPLE, "")
        (folder / "config.toml").write_text(cfg)
    rep = write_report([tmp_path], tmp_path / "rep")
    table = next(t for t in rep.tables if t.key == "humans")
    assert [r[1] for r in table.rows] == ["carla", "human1"]
