"""The estimate before step 1 (issue 44, "No hidden hour"): its arithmetic from given
rates (what the cache holds skipped), which fleet step it takes (the arms' measured
pushes, measured whole steps, else the backends' nominal), the plan ``testbed trial``
prints before anything moves, and ``--dry-run``, which prints it and touches nothing."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from testbed.cli import main
from testbed.experiments.fleet_config import FleetConfig, parse_config
from testbed.experiments.pace import FleetPace, GradPace, fleet_pace
from testbed.experiments.theta0 import CacheState
from testbed.experiments.time_plan import (
    Plan,
    Target,
    duration,
    fleet_steps,
    plan_lines,
    run_seconds,
    theta0_phases,
)
from testbed.records.run_dir import RunDir

ROOT = Path(__file__).resolve().parents[2]
PACE = FleetPace(8.5, "nominal", "given", teleop_violation=0.02, policy_violation=0.1)
GRAD = GradPace(1.0, 0.5, "given")
PAPER = {"demos": 375, "critic_transitions": 1000, "pretrain_steps": 1000,
         "critic_pretrain_steps": 3000}
TWO_BY_TWO = [{"name": "a"}, {"name": "b"}]  # 2 twin hosts x 2 arms: 4 arms
TINY = """[trial]
steps = 2
[humans]
count = 1
[learning]
ensemble_size = 2
batch_size = 16
demos = 12
critic_transitions = 6
pretrain_steps = 2
[[hosts]]
name = "cell0"
"""

TINY_PROTOCOL = """[fleet.humans]
count = 1
[fleet.learning]
ensemble_size = 2
batch_size = 16
demos = 12
critic_transitions = 6
pretrain_steps = 2
[[fleet.hosts]]
name = "cell0"
"""


def paper_fleet(**algorithm: Any) -> FleetConfig:
    return parse_config({"hosts": TWO_BY_TWO, "learning": PAPER,
                         "algorithm": {"t_R": 5, **algorithm}})


def empty(tmp: Path) -> CacheState:
    return CacheState(tmp / "theta0", tmp / "demos.npz", False, 0, False, 0)


def grad(lc: Any, critics: Any) -> GradPace:
    return GRAD


def test_the_phases_at_given_rates() -> None:
    cfg = paper_fleet()
    phases = theta0_phases(Target(cfg, ("safety",), empty(Path("/c"))), PACE, grad)
    got = {p.name: (p.count, p.fleet_steps, p.seconds, p.skipped) for p in phases}
    # 4 arms at once; 2% of teleop pushes violate, each 5 steps of reset; +1: a pair is
    # kept on the step after its push
    collect = math.ceil(375 * (1 + 0.02 * 5) / 4) + 1
    rollout = math.ceil(1000 * (1 + 0.1 * 5) / 4) + 1
    assert (collect, rollout) == (105, 376)
    assert got == {
        "collect demonstrations": (375, collect, collect * 8.5, False),
        "pretrain the policy": (1000, 0, 1000 * 1.0, False),
        "roll out the policy": (1000, rollout, rollout * 8.5, False),
        "pretrain the critics": (3000, 0, 3000 * 0.5, False),
    }
    assert fleet_steps(0, 4, 0.5, 5) == 0
    # a run: a fleet step and a training step (policy and critic) per step; BC trains
    # nothing, an evaluation (no grad) neither, a measured whole step holds its training
    assert run_seconds(cfg, "cur", 250, PACE, grad, ["safety"]) == 250 * (8.5 + 1.0 + 0.5)
    assert run_seconds(cfg, "fleet-ed", 250, PACE, grad) == 250 * (8.5 + 1.0)
    assert run_seconds(cfg, "bc", 250, PACE, grad) == 250 * 8.5
    assert run_seconds(cfg, "cur", 250, PACE, None) == 250 * 8.5
    whole = FleetPace(12.0, "measured step", "rows")
    assert run_seconds(cfg, "cur", 10, whole, grad, ["safety"]) == 120.0
    three = cfg.model_copy(update={"learning": cfg.learning.model_copy(
        update={"gradient_steps": 3})})
    assert run_seconds(three, "cur", 10, PACE, grad, ["safety"]) == 10 * (8.5 + 3 * 1.5)


def test_what_the_cache_holds_is_skipped_and_said(tmp_path: Path) -> None:
    cfg = paper_fleet()
    part = CacheState(tmp_path, tmp_path / "d.npz", False, 120, True, 400)
    phases = {p.name: p for p in theta0_phases(Target(cfg, ("safety",), part), PACE, grad)}
    c = phases["collect demonstrations"]
    assert c.fleet_steps == math.ceil(255 * 1.1 / 4) + 1 and not c.skipped
    assert c.note == f"120 kept in {tmp_path / 'd.npz'}, 255 to go"
    p = phases["pretrain the policy"]
    assert p.skipped and p.seconds == 0 and "checkpointed" in p.note
    r = phases["roll out the policy"]
    assert r.fleet_steps == math.ceil(600 * 1.5 / 4) + 1 and "400 kept" in r.note
    assert phases["pretrain the critics"].seconds == 1500
    done = CacheState(tmp_path, tmp_path / "d.npz", True, 375, False, 0)
    only = theta0_phases(Target(cfg, ("safety",), done), PACE, grad)
    assert [(p.name, p.skipped, p.seconds) for p in only] == [("theta_0", True, 0.0)]
    # no critic: no rollouts, no critic steps (and nothing measured for them)
    none = {p.name: p for p in theta0_phases(Target(cfg, (), empty(tmp_path)), PACE, grad)}
    assert none["roll out the policy"].skipped and none["pretrain the critics"].skipped
    assert none["roll out the policy"].note == "no critic to pretrain"
    # two theta_0 of the same arms draw on one collection: the second collects nothing
    planned: dict[Path, int] = {}
    first = theta0_phases(Target(cfg, ("safety",), empty(tmp_path)), PACE, grad, planned)
    second = theta0_phases(Target(cfg, (), empty(tmp_path)), PACE, grad, planned)
    assert not first[0].skipped and second[0].skipped and second[0].seconds == 0


def test_the_printed_plan_has_each_phase_its_total_and_its_sources(tmp_path: Path) -> None:
    cfg = paper_fleet()
    phases = theta0_phases(Target(cfg, ("safety",), empty(tmp_path)), PACE, grad)
    plan = Plan(phases, PACE, GRAD)
    lines = plan_lines(plan, "gui", "--config lab.toml")
    text = "\n".join(lines)
    assert lines[0].startswith("Before step 1")
    total = 105 * 8.5 + 1000 + 376 * 8.5 + 1500
    assert re.search(rf"^  total +~{re.escape(duration(total))}$", text, re.M)
    assert duration(total) == "1 h 50 min"  # 6588.5 s
    assert re.search(r"^  collect demonstrations +375 pairs +105 +~14 min 52 s$", text, re.M)
    assert "fleet step 8.5 s: given" in text and "gradient step: policy 1 s" in text
    assert "the humans' time to choose each teleop push" in text  # gui: not counted
    assert ("testbed collect --config lab.toml, then testbed pretrain --config lab.toml"
            in text and "--policy learner.pt" in text)
    assert "--policy" not in "\n".join(plan_lines(plan, "gui", "X", policy=False))
    # one theta_0 of several (a protocol's way): its phases are named for whom, and the
    # hint stays; runs alone (theta_0 cached) need none
    labelled = theta0_phases(Target(cfg, (), empty(tmp_path), "for cur-weighted"), PACE, grad)
    assert labelled[0].name == "collect demonstrations (for cur-weighted)"
    assert "theta_0: skip it" in "\n".join(plan_lines(Plan(labelled, PACE, GRAD), "gui"))
    done = CacheState(tmp_path, tmp_path / "d.npz", True, 375, False, 0)
    cached = theta0_phases(Target(cfg, (), done), PACE, grad)
    assert not Plan(cached, PACE, None).pretrains
    assert "theta_0:" not in "\n".join(plan_lines(Plan(cached, PACE, None), "gui"))


def _run(folder: Path, cfg: FleetConfig, rows: list[dict[str, Any]]) -> None:
    run = RunDir(folder)
    run.path.mkdir(parents=True)
    run.write_config(cfg)
    (run.path / "steps.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))


def _row(t: int, robots: list[str], push: list[float] | None, duration_s: float,
         mode: str = "teleop", violation: bool = False) -> dict[str, Any]:
    arms = []
    for i, r in enumerate(robots):
        arm: dict[str, Any] = {"robot": r, "mode": mode, "violation": violation}
        if push is not None:
            arm["readings"] = {"push_s": push[i]}
        arms.append(arm)
    return {"t": t, "robots": arms, "duration_s": duration_s}


def test_the_fleet_step_is_measured_when_the_lab_has_runs_else_nominal(tmp_path: Path
                                                                         ) -> None:
    cfg = parse_config({"hosts": [{"name": "a"}]})
    robots = cfg.robot_names
    out = tmp_path / "runs"
    nominal = fleet_pace(cfg, [out])
    assert nominal.kind == "nominal" and nominal.step_s == 0.01
    assert "declared by backend twin" in nominal.source and "no earlier runs" in nominal.source
    # a run of other arms says nothing of these
    other = parse_config({"hosts": [{"name": "elsewhere"}]})
    _run(out / "other", other, [_row(t, other.robot_names, [9.0, 9.0], 20.0)
                                for t in range(30)])
    assert fleet_pace(cfg, [out]).kind == "nominal"
    # whole steps measured (no host readings): their median
    _run(out / "steps", cfg, [_row(t, robots, None, 2.0 + (t % 3)) for t in range(30)])
    by_step = fleet_pace(cfg, [out])
    assert (by_step.kind, by_step.step_s) == ("measured step", 3.0)
    assert by_step.includes_learning and "30 steps of 1 run(s)" in by_step.source
    # pushes measured on the host: per step the slowest arm's, the median over steps;
    # 25 teleop pushes of which 5 violated: the teleop rate is measured, the policy's not
    rows = [_row(t, robots, [7.0 + t % 2, 8.0 + t % 5], 30.0, violation=t % 10 == 0)
            for t in range(25)]
    _run(out / "pushes", cfg, rows)
    pushed = fleet_pace(cfg, [out])
    assert pushed.kind == "measured push" and not pushed.includes_learning
    assert pushed.step_s == 10.0  # max(7|8, 8..12) per step: 8..12, five times each
    assert "over 25 steps of 1 run(s)" in pushed.source
    assert pushed.teleop_violation == pytest.approx(6 / 110)
    assert "teleop's measured over 110 pushes" in pushed.rates_source
    assert "policy's assumed" in pushed.rates_source
    # a YuMi fleet with nothing on record: the plugin's nominal push
    yumi = parse_config({"hosts": [{
        "name": "y", "backend": "yumi", "camera": "0", "controller_url": "http://192.0.2.1",
        "arms": [{"name": "left", "crop": [0, 0, 300, 300], "calibration": "/c/l.json"}]}]},
        check_files=False)
    assert fleet_pace(yumi, [out]).step_s == 8.5


def _tiny(tmp_path: Path) -> Path:
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(TINY)
    return cfg


def test_dry_run_prints_the_plan_and_touches_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = _tiny(tmp_path)
    out = tmp_path / "runs"
    assert main(["trial", "--config", str(cfg), "--out", str(out), "--dry-run"]) == 0
    got = capsys.readouterr().out
    for phase in ("collect demonstrations", "pretrain the policy", "roll out the policy",
                  "pretrain the critics", "trial cur", "total"):
        assert re.search(rf"^  {phase} ", got, re.M), phase
    assert not out.exists()
    proto = tmp_path / "p.toml"
    proto.write_text(f'name = "p"\ntrials = 2\nalgorithms = ["bc", "cur"]\nsteps = 3\n'
                     f'evaluate_steps = 0\nout = "{tmp_path / "proto"}"\n' + TINY_PROTOCOL)
    assert main(["protocol", str(proto), "--dry-run"]) == 0
    got = capsys.readouterr().out
    assert re.search(r"^  training runs +12 steps +12 .*\(4 of 4 runs to go\)$", got, re.M)
    assert "testbed collect --config " + str(proto) in got
    assert not (tmp_path / "proto").exists()
    assert main(["collect", "--config", str(proto), "--dry-run"]) == 0
    assert main(["pretrain", "--config", str(proto), "--dry-run"]) == 0
    assert not (tmp_path / "proto").exists()


@pytest.mark.slow
def test_trial_prints_its_plan_before_anything_moves(tmp_path: Path) -> None:
    """The plan is the first thing the trial says: before the collection's first report
    (stdout and stderr into one pipe, in the order written)."""
    cfg = _tiny(tmp_path)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "TESTBED_PROGRESS": "plain"}
    proc = subprocess.run([sys.executable, "-m", "testbed.cli", "trial", "--config", str(cfg),
                           "--out", str(tmp_path / "runs")], cwd=tmp_path, env=env,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:]
    text = proc.stdout
    first = text.index("Before step 1")
    assert first < text.index("collect: started") < text.index("trial: started")
    plan = text[first:text.index("collect: started")]
    assert re.search(r"^  collect demonstrations +12 pairs +\d+ +~\d+ s$", plan, re.M)
    assert re.search(r"^  total +~\d+ (s|min \d\d s)$", plan, re.M)
    assert "gradient step: policy" in plan and "timed here just now" in plan


class _Clock:
    """A clock whose timed steps last the given seconds, in order (each timed step
    reads it twice: before and after)."""

    def __init__(self, steps: list[float]) -> None:
        self.steps, self.now, self.reads = list(steps), 0.0, 0

    def __call__(self) -> float:
        self.reads += 1
        if self.reads % 2 == 0:
            self.now += self.steps.pop(0)
        return self.now


def test_the_gradient_rate_is_the_median_of_a_few_steps_after_a_warm_up() -> None:
    """One step alone swung about 2x between runs: the real learner (tiny sizes) takes a
    warm-up step of each kind, then up to 3 timed within the budget; the median is the
    rate and a large spread is said, as the machine's load."""
    from testbed.experiments.pace import measure_gradient
    from testbed.learning.learning_config import LearningConfig

    lc = LearningConfig(ensemble_size=2, batch_size=16)
    clock = _Clock([1.0, 3.0, 2.0, 0.5, 0.5, 0.52])
    got = measure_gradient(lc, ("safety",), clock, budget_s=10.0)
    assert (got.policy_s, got.critic_s) == (2.0, 0.5)
    assert clock.reads == 12 and not clock.steps  # 3 timed of each, warm-ups untimed
    assert got.source.startswith("the median of 3 and 3 timed here just now after a "
                                 "warm-up (ensemble 2, batch 16, device cpu)")
    assert got.source.endswith("; spread policy 1-3 s: this machine's load")
    # a step as long as the budget: one timed (and no spread to say); no critic: 0 s
    slow = _Clock([1.5, 9.0])
    got = measure_gradient(lc, (), slow, budget_s=2.0)
    assert (got.policy_s, got.critic_s, slow.steps) == (1.5, 0.0, [9.0])
    assert "the median of 1 timed" in got.source and "spread" not in got.source
