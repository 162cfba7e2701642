"""Protocol runs: counterbalanced orders, prompts before every run, Esc-stopped runs
(stopped, resumable, left out of the report), and the loop's refused pushes.

The protocol test drives real twin hosts (agent processes, PyBullet) and the real
learner, sized down (one host, tiny ensemble) so the whole protocol takes seconds.
The loop test uses small doubles for the hosts and the learner: what it checks is the
loop's own bookkeeping of a push the host refused, which no twin host produces.
"""

from __future__ import annotations

import json
import time
import tomllib
from collections import Counter
from collections.abc import Mapping, Sequence
from itertools import pairwise
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from testbed.core.config import ConfigError
from testbed.core.humans import HumansStopRequested
from testbed.core.types import IMAGE_SIZE, ArmObservation, FleetStatus, PushResult
from testbed.experiments.hooks import TrialHooks
from testbed.experiments.protocol import Protocol, run_protocol, williams_square
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import get_algorithm
from testbed.fleet.loop import FleetLoop
from testbed.records.steps import RunWriter, read_steps, validate_step
from testbed.results.report import write_report

ROOT = Path(__file__).resolve().parents[2]
ALGOS = ["bc", "random", "fleet-ed", "cur"]


# ------------------------------------------------------------------ the orders
def test_williams_square_is_a_latin_square_balanced_for_carryover() -> None:
    for n in (2, 3, 4, 5):
        rows = williams_square(n)
        assert len(rows) == (n if n % 2 == 0 else 2 * n)
        for row in rows:
            assert sorted(row) == list(range(n))
        for pos in range(n):  # every symbol equally often in every position
            counts = np.bincount([r[pos] for r in rows], minlength=n)
            assert len(set(counts.tolist())) == 1
        # every ordered pair (a right before b) equally often: once (even n), twice (odd)
        follows = Counter(pair for r in rows for pair in pairwise(r))
        assert len(follows) == n * (n - 1)
        assert set(follows.values()) == {1 if n % 2 == 0 else 2}


def test_counterbalanced_order_is_seeded_balanced_and_different_per_trial() -> None:
    proto = Protocol(name="p", trials=4, algorithms=ALGOS, seeds=[0, 1, 2, 3],
                     order="counterbalanced")
    orders = [proto.run_order(k) for k in range(4)]
    assert all(sorted(o) == sorted(ALGOS) for o in orders)
    assert len({tuple(o) for o in orders}) == 4
    for pos in range(4):  # each algorithm runs once in each position over the 4 trials
        assert sorted(o[pos] for o in orders) == sorted(ALGOS)
    assert orders == [proto.run_order(k) for k in range(4)]  # a rerun: the same orders
    other = proto.model_copy(update={"seeds": [7, 8, 9, 10]})
    assert [other.run_order(k) for k in range(4)] != orders  # seeded by the protocol
    fixed = Protocol(name="p", trials=2, algorithms=ALGOS)
    assert fixed.run_order(0) == fixed.run_order(1) == ALGOS


def test_prompt_fields_and_the_legacy_switch() -> None:
    assert Protocol(name="p").prompt_when == "never"
    legacy = Protocol.model_validate({"name": "p", "prompt_between_trials": True})
    assert legacy.prompt_when == "between_trials"
    with pytest.raises(ValueError, match="prompt_when"):
        Protocol.model_validate({"name": "p", "prompt_when": "sometimes"})
    with pytest.raises(ValueError, match="order"):
        Protocol.model_validate({"name": "p", "order": "shuffled"})
    physical = tomllib.loads((ROOT / "protocols" / "physical.toml").read_text())
    assert physical["prompt_when"] == "before_each_run"
    assert physical["order"] == "counterbalanced"


# ------------------------------------------------------------------ the report
def _fake_run(folder: Path, status: str | None, steps: int, **meta: Any) -> Path:
    folder.mkdir(parents=True)
    with RunWriter(folder) as w:
        for t in range(steps):
            w.write_step({"t": t, "robots": [
                {"robot": "h/a", "mode": "autonomous", "human": None, "action": 1,
                 "success": t % 2 == 0, "violation": False, "uncertainty": 0.1,
                 "risk": 0.0, "key": [0.0]}]})
    info: dict[str, Any] = {"options": {"algorithm": folder.name.split("-t")[0]}, **meta}
    if status is not None:
        info["status"] = status
    (folder / "run.json").write_text(json.dumps(info))
    return folder


def test_report_leaves_unfinished_runs_out_and_says_so_in_one_line(tmp_path: Path) -> None:
    _fake_run(tmp_path / "bc-t0", "complete", 4)
    _fake_run(tmp_path / "cur-t0", None, 4)  # written before run statuses: still counted
    _fake_run(tmp_path / "cur-t1", "stopped", 2, stopped_at=2)
    _fake_run(tmp_path / "bc-t1", "running", 1)  # in progress, or killed
    report = write_report([tmp_path], tmp_path / "rep")
    assert sorted(r.path.name for r in report.runs) == ["bc-t0", "cur-t0"]
    assert len(report.notes) == 1
    note = report.notes[0]
    assert "left out 2 unfinished run(s)" in note and "\n" not in note
    assert "cur-t1 (stopped at step 2)" in note and "bc-t1 (running)" in note
    md = (tmp_path / "rep" / "report.md").read_text()
    assert note in md and "| bc | 1 |" in md and "| cur | 1 |" in md

    only = tmp_path / "only"
    _fake_run(only / "cur-t0", "stopped", 1, stopped_at=1)
    with pytest.raises(ConfigError, match="no finished run; left out 1"):
        write_report([only], only)


def test_an_evaluation_never_lands_in_a_training_algorithms_row(tmp_path: Path) -> None:
    _fake_run(tmp_path / "cur-t0", "complete", 4)
    _fake_run(tmp_path / "cur-t1", "complete", 4)
    ev = _fake_run(tmp_path / "eval-cur-t0-s0", "complete", 6)
    old = _fake_run(tmp_path / "eval-x-s0", "complete", 2)  # before labels: evaluate only
    for run, options in ((ev, {"algorithm": "bc", "evaluate": True, "label": "eval:cur"}),
                         (old, {"algorithm": "bc", "evaluate": True})):
        meta = json.loads((run / "run.json").read_text())
        (run / "run.json").write_text(json.dumps(meta | {"options": options}))
    report = write_report([tmp_path], tmp_path / "rep")
    learning, _, evaluation = report.markdown.partition("Evaluation (the paper's 8.3.4")
    assert "| cur | 2 |" in learning and "eval" not in learning and "| bc |" not in learning
    assert "| eval:cur | 1 |" in evaluation and "| eval:policy | 1 |" in evaluation
    assert evaluation.splitlines()[2].startswith("| algorithm | trials | successes | "
                                                 "hard_resets | idle_time |")
    rows = (tmp_path / "rep" / "report.csv").read_text().splitlines()
    assert [r.split(",")[0] for r in rows[1:]] == ["cur"]
    rows = (tmp_path / "rep" / "report-eval.csv").read_text().splitlines()
    assert sorted(r.split(",")[:2] for r in rows[1:]) == [["eval:cur", "1"], ["eval:policy", "1"]]


# ------------------------------------------------------------------ refused pushes
class _Hosts:
    """Two arms; the host refuses every push of ``h/a`` (its cube is not in the picture)."""

    def __init__(self) -> None:
        self.robot_names = ["h/a", "h/b"]

    def observe(self) -> dict[str, ArmObservation]:
        img = np.zeros((IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8)
        return {r: ArmObservation(r, img, False, (0.0, 0.0), 1) for r in self.robot_names}

    def execute(self, pushes: Mapping[str, int], resets: Sequence[str]) -> dict[str, Any]:
        return {"h/a": PushResult("h/a", pushes.get("h/a"), False, False,
                                  refused="cube not found"),
                "h/b": PushResult("h/b", pushes.get("h/b"), "h/b" in pushes, False)}


class _Learner:
    def __init__(self) -> None:
        self.transitions: list[np.ndarray] = []

    def act(self, images: np.ndarray) -> Any:
        n = len(images)
        z = np.zeros(n)
        return SimpleNamespace(actions=np.full(n, 2), uncertainty=z, risk=z, goal_risk=z,
                               novelty=z)

    def add_human(self, images: np.ndarray, actions: np.ndarray,
                  labellers: np.ndarray | None = None) -> None:
        raise AssertionError("no human label expected")

    def add_transitions(self, images: np.ndarray, actions: np.ndarray, *rest: Any) -> None:
        self.transitions.append(actions)

    def train_step(self) -> dict[str, float]:
        return {}


def test_a_refused_push_is_logged_as_refused_with_its_reason(tmp_path: Path) -> None:
    learner = _Learner()
    algorithm = get_algorithm("cur", AlgorithmConfig(), 2, 1, 0)
    with RunWriter(tmp_path) as writer:
        loop = FleetLoop(hosts=_Hosts(), humans=ScriptedHumans(), learner=learner,
                         algorithm=algorithm, writer=writer, steps=3, num_humans=1,
                         t_T=3, t_R=5)
        before = time.time()
        try:
            outcomes = [loop.step(t) for t in range(3)]
        finally:
            loop.close()
    rows = read_steps(tmp_path)  # validated on the way in and out
    assert len(rows) == 3
    for row in rows:
        a, b = row["robots"]
        assert a == {**a, "mode": "refused", "refused": "cube not found", "human": None,
                     "success": False, "action": 2}
        assert b["mode"] == "autonomous" and b["success"] and "refused" not in b
        assert before <= row["wall_time"] <= time.time()
        assert 0 <= row["duration_s"] < 5
    # the refused arm is in no counter and gives the critics no transition
    status: FleetStatus = outcomes[-1].status
    assert (status.successes, status.human_actions, status.idle_time) == (3, 0, 0)
    assert [t.tolist() for t in learner.transitions] == [[2], [2]]  # h/b's pushes only


# ------------------------------------------------------------------ a protocol on twins
FLEET = {
    "hosts": [{"name": "cell0"}],
    "humans": {"count": 1},
    "learning": {"ensemble_size": 2, "batch_size": 16, "demos": 16,
                 "critic_transitions": 8, "pretrain_steps": 4},
}


class _StopAt(ScriptedHumans):
    """The operator presses Esc (and confirms) during step ``k``'s overview."""

    def __init__(self, k: int) -> None:
        super().__init__()
        self.k = k

    def show(self, t: int, status: FleetStatus) -> None:
        if t == self.k:
            raise HumansStopRequested("Esc")


@pytest.mark.slow
def test_protocol_prompts_every_run_counterbalances_and_resumes_a_stopped_run(
    tmp_path: Path,
) -> None:
    proto = Protocol.model_validate({
        "name": "mini", "trials": 2, "algorithms": ["bc", "cur"], "steps": 4,
        "seeds": [5, 6], "out": str(tmp_path / "proto"), "prompt_when": "before_each_run",
        "order": "counterbalanced", "fleet": FLEET, "evaluate_steps": 0,
    })
    orders = [proto.run_order(k) for k in range(2)]
    assert orders[0] == orders[1][::-1]  # 2 algorithms: each runs first once
    plan = [f"{a}-t{k}" for k in range(2) for a in orders[k]]
    stop_in = plan[1]
    stops = [stop_in]  # the operator presses Esc once, in the second run
    asked: list[str] = []

    class Hooks(TrialHooks):
        def before_run(self, name: str) -> bool:
            asked.append(name)
            return True

        def humans(self, name: str) -> ScriptedHumans:
            if name in stops:
                stops.remove(name)
                return _StopAt(1)
            return ScriptedHumans()

    first = run_protocol(proto, ask=False, hooks=Hooks())
    out = tmp_path / "proto"
    assert asked == plan[:2]  # the hook ran before each run, and the protocol stopped
    stopped = out / stop_in
    meta = json.loads((stopped / "run.json").read_text())
    assert meta["status"] == "stopped" and meta["stopped_at"] == 2
    assert not (stopped / "summary.json").exists()
    assert [s["t"] for s in read_steps(stopped)] == [0, 1]
    assert [r.path.name for r in first.runs] == [plan[0]]
    assert len(first.notes) == 1 and stop_in in first.notes[0]

    final = run_protocol(proto, ask=False, hooks=Hooks())
    assert asked == plan[:2] + plan[1:]  # the stopped run was resumed, then the rest ran
    assert sorted(r.path.name for r in final.runs) == sorted(plan) and not final.notes
    steps = read_steps(stopped)
    assert [s["t"] for s in steps] == [0, 1, 2, 3]
    for s in steps:
        validate_step(s)
        assert s["wall_time"] > 0 and s["duration_s"] >= 0
    for k in range(2):
        for pos, alg in enumerate(orders[k]):
            run = out / f"{alg}-t{k}"
            meta = json.loads((run / "run.json").read_text())
            assert meta["status"] == "complete" and (run / "summary.json").exists()
            assert meta["protocol"] == {"name": "mini", "trial": k, "position": pos,
                                        "order": orders[k], "ordering": "counterbalanced"}
            assert (run / "hosts" / "cell0.log").stat().st_size > 0
