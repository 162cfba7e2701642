"""Matched baselines (issue 12, item 1): ``random_budget = "match:<algorithm>"`` gives
Random, in each trial, the human effort the named algorithm spent in the same trial.

Hand-built records check the arithmetic; the protocol test runs real twin hosts and the
real learner (sized down) and checks Random's run spent what C.U.R.'s did."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from testbed.core.config import ConfigError
from testbed.experiments.fleet_config import parse_config
from testbed.experiments.protocol import Protocol, matched_budget, run_protocol
from testbed.records.run_dir import RunDir
from testbed.records.steps import RunWriter, read_steps

ROOT = Path(__file__).resolve().parents[2]


def _run(folder: Path, modes: list[list[str]], *, finished: bool = True) -> Path:
    """A run whose step t has one arm per entry of ``modes[t]``."""
    folder.mkdir(parents=True)
    with RunWriter(folder) as w:
        for t, row in enumerate(modes):
            w.write_step({"t": t, "robots": [
                {"robot": f"h/{i}", "mode": m,
                 "human": 0 if m in ("teleop", "reset") else None,
                 "action": 1 if m in ("teleop", "autonomous") else None,
                 "success": False, "violation": False, "uncertainty": 0.1, "risk": 0.0,
                 "key": [0.0]} for i, m in enumerate(row)]})
    if finished:
        RunDir(folder).summary.write_text("{}")
    return folder


def test_matched_budget_is_the_runs_human_actions_over_humans_times_steps(
        tmp_path: Path) -> None:
    modes = [["teleop", "autonomous", "reset"],   # 2 human actions
             ["teleop", "idle", "autonomous"],    # 1 (idle: no human)
             ["autonomous"] * 3,                  # 0
             ["reset", "reset", "teleop"]]        # 3
    run = _run(tmp_path / "cur-t0", modes)
    assert matched_budget(run, num_humans=2) == pytest.approx(6 / (2 * 4))
    assert matched_budget(run, num_humans=1) == 1.0  # more than one per step: capped
    with pytest.raises(ConfigError, match="has not finished"):
        matched_budget(_run(tmp_path / "cur-t1", modes, finished=False), 2)


def _proto(**over: object) -> Protocol:
    data: dict[str, object] = {
        "name": "m", "trials": 2, "algorithms": ["random", "bc", "cur"],
        "fleet": {"algorithm": {"random_budget": "match:cur"}}}
    data.update(over)
    return Protocol.model_validate(data)


def test_random_runs_after_the_algorithm_it_matches_in_every_order() -> None:
    assert _proto().run_order(0) == ["bc", "cur", "random"]
    p = _proto(trials=6, order="counterbalanced", seeds=[0, 1, 2, 3, 4, 5],
               algorithms=["random", "bc", "cur", "fleet-ed"])
    for k in range(6):
        order = p.run_order(k)
        assert sorted(order) == ["bc", "cur", "fleet-ed", "random"]
        assert order.index("random") > order.index("cur")
    plain = Protocol.model_validate({"name": "m", "algorithms": ["random", "cur"]})
    assert plain.run_order(0) == ["random", "cur"]  # a number: the order is untouched


@pytest.mark.parametrize(("fleet", "algorithms", "field"), [
    ({"random_budget": "match:fleet-ed"}, ["random", "cur"], "'fleet-ed' must be another"),
    ({"random_budget": "match:random"}, ["random", "cur"], "must be another"),
    ({"random_budget": "matches cur"}, ["random", "cur"], "algorithm.random_budget"),
    ({"random_budget": 1.5}, ["random", "cur"], "algorithm.random_budget"),
])
def test_bad_budgets_are_one_line_config_errors(fleet: dict[str, object],
                                                algorithms: list[str], field: str) -> None:
    from testbed.experiments.protocol import load_protocol

    with pytest.raises(ConfigError, match=field) as err:
        path = Path(os.environ.get("TMPDIR", "/tmp")) / f"budget-{os.getpid()}.toml"
        budget = fleet["random_budget"]
        value = f'"{budget}"' if isinstance(budget, str) else str(budget)
        path.write_text(f'name = "m"\nalgorithms = {json.dumps(algorithms)}\n\n'
                        f"[fleet.algorithm]\nrandom_budget = {value}\n")
        try:
            load_protocol(path)
        finally:
            path.unlink()
    assert "\n" not in str(err.value)


def test_a_matched_budget_in_a_trial_alone_exits_2_with_one_line(tmp_path: Path) -> None:
    cfg = tmp_path / "fleet.toml"
    cfg.write_text('[algorithm]\nname = "random"\nrandom_budget = "match:cur"\n')
    parse_config({"algorithm": {"random_budget": "match:cur"}}, "x")  # valid as config
    proc = subprocess.run(
        [sys.executable, "-m", "testbed.cli", "trial", "--config", str(cfg), "--steps", "1",
         "--out", str(tmp_path / "runs")],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "random_budget" in lines[0] and "protocol" in lines[0]
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


@pytest.mark.slow
def test_protocol_gives_random_the_effort_cur_spent_in_the_same_trial(
        tmp_path: Path) -> None:
    steps = 24
    proto = Protocol.model_validate({
        "name": "match", "trials": 2, "algorithms": ["random", "cur"], "steps": steps,
        "seeds": [3, 4], "out": str(tmp_path / "proto"), "evaluate_steps": 0,
        "fleet": {"hosts": [{"name": "cell0"}, {"name": "cell1"}], "humans": {"count": 2},
                  "algorithm": {"random_budget": "match:cur", "u_hat": 0.0, "t_T": 2,
                                "t_R": 2, "t_I": 0},
                  "learning": {"ensemble_size": 2, "batch_size": 16, "demos": 16,
                               "critic_transitions": 8, "pretrain_steps": 4}},
    })
    run_protocol(proto, ask=False)
    out = tmp_path / "proto"
    for k in range(2):
        cur = read_steps(out / f"cur-t{k}")
        rnd = read_steps(out / f"random-t{k}")
        used = [sum(r["mode"] in ("teleop", "reset") for row in rows for r in row["robots"])
                for rows in (cur, rnd)]
        meta = json.loads((out / f"random-t{k}" / "run.json").read_text())
        budget = used[0] / (2 * steps)
        assert meta["budget_matched"] == {"run": f"cur-t{k}",
                                          "random_budget": pytest.approx(budget)}
        resolved = (out / f"random-t{k}" / "config.toml").read_text()
        assert f"random_budget = {budget!r}"[:24] in resolved
        assert meta["protocol"]["order"] == ["cur", "random"]
        # Random spends its budget to within a couple of human-steps (draws and holds)
        assert abs(used[1] - used[0]) <= max(3, 0.1 * used[0]), used
