"""The planner's promise in a world whose truth is known: fitted at one fleet size, it
predicts what the real loop measures at others.

The world (``plan_fakes``) has the twin's shape of trouble: an arm falls into a state
where it asks at 0.9 and violates 40 times as often until a human's push fixes it. The
fit sees 4 runs at N = 6 arms, M = 2 humans; the loop then runs 4 seeds at three other
points, with one person (most requests unserved: trouble piles up), with more arms and
with more people. Every run is seeded, so the test is deterministic; it allows one miss
of the 9 (point, metric) checks, as 95% intervals would.
"""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
from plan_fakes import Trouble, World, run_world

from testbed.people.people_config import HumanProfile
from testbed.planning.plan import PlanOptions, write_plan
from testbed.planning.plan_check import write_checks

WORLD = World(policy=(0.2, 0.005), trouble=Trouble())
PEOPLE = [HumanProfile(name="ana"), HumanProfile(name="bo", latency=1)]


@pytest.mark.slow
def test_fitted_at_one_point_the_plan_holds_at_others(tmp_path: Path) -> None:
    fit = tmp_path / "fit"
    for s in range(4):
        run_world(fit / f"cur-t{s}", WORLD, arms=6, people=PEOPLE, steps=200, seed=s)
    sweep = tmp_path / "sweep"
    points = ((6, 1), (10, 2), (6, 3))
    for n, m in points:
        for s in range(4):
            run_world(sweep / f"n{n}m{m}s{s}", WORLD, arms=n, steps=200, seed=50 + s,
                      people=[PEOPLE[h % 2] for h in range(m)])
    options = PlanOptions((6, 10), (1, 2, 3), runs=4, replicates=300)
    plan = write_checks(write_plan([fit], options, tmp_path / "plan"), [sweep], options)
    with (tmp_path / "plan" / "plan-check.csv").open() as f:
        rows = [r for r in csv.DictReader(f)
                if r["metric"] in ("idle_time", "human_actions", "hard_resets")]
    assert {(int(r["N"]), int(r["M"])) for r in rows} == set(points) and len(rows) == 9
    missed = [r for r in rows if r["inside"] != "1"]
    assert len(missed) <= 1, (missed, plan.markdown)
    # one person drowns in trouble: most of their requests go unserved, and the plan says so
    one = {r["metric"]: float(r["measured"]) for r in csv.DictReader(
        (tmp_path / "plan" / "plan-check.csv").open()) if r["M"] == "1"}
    assert one["unserved"] > 0.5 and one["hard_resets"] > 10
