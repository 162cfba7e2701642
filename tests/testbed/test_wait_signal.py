"""How long each arm has waited for a human reaches every place it must: the checklist
"A new signal that is not learned (a wait, a count)" of docs/ARCHITECTURE.md, as tests.

Why: the wait is counted once, by the allocator (``Allocator.waited``), where the
allocation is decided, and read everywhere else: the next step's priority functions
(``PrioritySignals.waited``), each arm's row (``"waited"``), a resume (the allocator's
``state_dict``), the consoles (``RobotStatus.waited``: the OpenCV overview's badge, the
web page's queue, ``fleet_doc``). A place skipped is silent (the row validates without
it, a priority reads zeros, a resume starts every wait again); the first test fails on
each. The second shows that a priority ranking by the wait ("d", longest wait first) is
a class and a registry entry, nothing else.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from loop_fakes import QuietLearner, RecordingPriority

from gui import draw
from gui.web.web_humans import fleet_doc
from testbed.core.types import IMAGE_SIZE, ArmObservation, PushResult
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import ALGORITHMS, AlgorithmSpec, get_algorithm
from testbed.fleet.allocator import Allocator
from testbed.fleet.loop import FleetLoop
from testbed.fleet.priorities import FloatArray, PrioritySignals, check_t
from testbed.monitor.monitor_config import MonitorConfig
from testbed.records.step_record import StepRecord
from testbed.records.steps import RunWriter, read_steps

ARMS = [f"h{i}/{a}" for i in range(3) for a in ("left", "right")]
STEPS = 40
SPLIT = 17


class _World:
    """Arms whose cubes leave the workspace on a schedule and come back with a reset;
    each image carries the step, so the learner's signals change with it."""

    def __init__(self, schedule: Mapping[int, Sequence[int]]) -> None:
        self.robot_names = list(ARMS)
        self.schedule = schedule
        self.violating = np.zeros(len(ARMS), dtype=bool)
        self.t = 0

    def observe(self) -> dict[str, ArmObservation]:
        img = np.zeros((IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8)
        img[0, 0, 0] = self.t % 256
        return {r: ArmObservation(r, img, bool(self.violating[i]), (0.5, 0.5), 1)
                for i, r in enumerate(ARMS)}

    def execute(self, pushes: Mapping[str, int], resets: Sequence[str]) -> dict[str, Any]:
        for r in resets:
            self.violating[ARMS.index(r)] = False
        out = set()
        for i in self.schedule.get(self.t, ()):
            if not self.violating[i] and ARMS[i] in pushes:
                self.violating[i] = True
                out.add(ARMS[i])
        self.t += 1
        return {r: PushResult(r, pushes.get(r), False, r in out) for r in ARMS}


class _Learner(QuietLearner):
    """Signals from the image (the step): the arms' order changes from step to step."""

    def act(self, images: np.ndarray) -> Any:
        n = len(images)
        t = images[:, 0, 0, 0].astype(float)
        u = ((t * 7 + np.arange(n) * 3) % 10) / 10 + 0.05
        return SimpleNamespace(actions=np.full(n, 1), uncertainty=u, risk=u / 2)


PARAMS = AlgorithmConfig(t_I=0, u_hat=0.5, r_hat=1.0, t_T=2, t_R=3)
SCHEDULE = {t: [(t * 5) % len(ARMS)] for t in range(0, STEPS, 2)}


def _loop(name: str, world: _World, writer: RunWriter, state: dict[str, Any] | None = None
          ) -> FleetLoop:
    algorithm = get_algorithm(name, PARAMS, len(ARMS), 1, seed=4)
    if state is not None:
        algorithm.load_state_dict(state)
    algorithm.priority = RecordingPriority(algorithm.priority)  # type: ignore[assignment]
    return FleetLoop(hosts=world, humans=ScriptedHumans(), learner=_Learner(),
                     algorithm=algorithm, writer=writer, steps=STEPS, num_humans=1,
                     t_T=PARAMS.t_T, t_R=PARAMS.t_R)


def _run(tmp: Path, split: int | None = None, *, drop_wait: bool = False
         ) -> tuple[list[dict[str, Any]], list[PrioritySignals], FleetLoop]:
    """Every row (timing dropped), the signals each step's priority was given, and the
    last loop (its status); resumed at ``split`` from the state through JSON and the
    rows, as ``testbed trial --resume`` does (``drop_wait``: a state without the waits)."""
    world = _World(SCHEDULE)
    tmp.mkdir()
    seen: list[PrioritySignals] = []
    with RunWriter(tmp) as writer:
        loop = _loop("cur-i", world, writer)
        for t in range(STEPS):
            if t == split:
                state = json.loads(json.dumps(loop.algorithm.state_dict()))
                if drop_wait:
                    del state["allocator"]["arm_waited"]
                seen += loop.algorithm.priority.seen  # type: ignore[attr-defined]
                loop.close()
                loop = _loop("cur-i", world, writer, state)
                loop.restore_counters(read_steps(tmp))
            loop.step(t)
        loop.close()
    seen += loop.algorithm.priority.seen  # type: ignore[attr-defined]
    rows = read_steps(tmp)
    for row in rows:
        row.pop("wall_time"), row.pop("duration_s")
    return rows, seen, loop


def _waits(row: Mapping[str, Any]) -> list[int]:
    return [r.get("waited", 0) for r in row["robots"]]


def test_a_wait_reaches_the_signals_the_rows_a_resume_and_both_consoles(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    rows, seen, loop = _run(tmp_path / "unbroken")
    assert len(seen) == STEPS
    # the rows: a wait only on an arm with no human, idle or queued, one more each step
    queued = idle = 0
    for before, row in zip([None, *rows], rows, strict=False):
        for i, r in enumerate(row["robots"]):
            if "waited" not in r:
                continue
            assert r["human"] is None, r
            idle += r["mode"] == "idle"
            queued += r["mode"] == "autonomous"
            assert r["waited"] == (1 if before is None else _waits(before)[i] + 1), r
    assert idle > 5 and queued > 5, (idle, queued)  # both kinds of wait happen
    assert max(max(_waits(row)) for row in rows) >= 4
    # the signals at step t: what the rows said up to step t - 1
    for t, signals in enumerate(seen):
        want = [0] * len(ARMS) if t == 0 else _waits(rows[t - 1])
        assert signals.waited_array(len(ARMS)).tolist() == want, t
    # read back from the rows
    images = np.zeros((len(ARMS), IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8)
    back = [StepRecord.from_row(row, 0, images, np.ones(len(ARMS), bool),
                                np.zeros((len(ARMS), 2), np.float32)) for row in rows]
    assert [[a.waited or 0 for a in b.arms] for b in back] == [_waits(r) for r in rows]
    # a resume carries every wait on: the same rows; a state without them does not
    assert max(_waits(rows[SPLIT - 1])) > 1, "an arm waits across the split"
    resumed, _, _ = _run(tmp_path / "resumed", SPLIT)
    assert resumed == rows
    forgot, _, _ = _run(tmp_path / "forgot", SPLIT, drop_wait=True)
    assert forgot[:SPLIT] == rows[:SPLIT] and forgot != rows
    # the consoles: the loop's status, the web page's queue, the OpenCV overview's badges
    last = {r["robot"]: r.get("waited") for r in rows[-1]["robots"]}
    assert [s.waited for s in loop.status.robots] == list(last.values())
    doc = fleet_doc(loop.status)
    assert [r["waited"] for r in doc["robots"]] == list(last.values())
    want_queue = sorted(((w, ARMS.index(r), r) for r, w in last.items() if w),
                        key=lambda x: (-x[0], x[1]))
    assert [(q["robot"], q["waited"]) for q in doc["queue"]] == [
        (r, w) for w, _, r in want_queue]
    assert doc["queue"], "someone waits at the last step"
    drawn: list[str] = []
    put_text = draw._text
    monkeypatch.setattr(draw, "_text", lambda img, text, *a, **k: (
        drawn.append(text), put_text(img, text, *a, **k)))
    draw.render_overview(loop.status)
    assert sorted(t for t in drawn if t.startswith("waited ")) == sorted(
        f"waited {w}" for w in last.values() if w)


# ---- a new priority by the wait: a class and a registry entry -------------------------
class LongestWaitPriority:
    """"d": the violating arm that has waited longest gets the next reset (first come,
    first served), instead of a random one among equal keys. Key (c,) with
    c = 1 + waited on a violating arm, 0 elsewhere; it reads no learned signal."""

    names: tuple[str, ...] = ("c",)
    reads: frozenset[str] = frozenset()

    def __init__(self, num_robots: int) -> None:
        self.num_robots = num_robots

    def keys(self, s: PrioritySignals) -> FloatArray:
        n = self.num_robots
        check_t(s.t)
        viol = s.violating_array(n)
        keys = np.where(viol, 1.0 + s.waited_array(n), 0.0)[:, None]
        keys[s.faulted_array(n)] = 0.0
        return keys

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        del state  # stateless: the wait is the allocator's


def _longest_wait(p: AlgorithmConfig, n: int, m: int, seed: np.random.SeedSequence,
                  allocator: Allocator, monitor: MonitorConfig) -> LongestWaitPriority:
    del p, m, seed, allocator, monitor
    return LongestWaitPriority(n)


_longest_wait.reads = LongestWaitPriority.reads  # type: ignore[attr-defined]


def _served_order(name: str, tmp: Path) -> list[str]:
    """The arms in the order a reset was assigned to them: four arms out at once-ish."""
    world = _World({0: [3], 1: [1], 2: [5], 3: [0], 4: [2]})
    params = AlgorithmConfig(t_I=0, t_T=1, t_R=3)
    algorithm = get_algorithm(name, params, len(ARMS), 1, seed=0)
    order: list[str] = []
    with RunWriter(tmp) as writer:
        loop = FleetLoop(hosts=world, humans=ScriptedHumans(), learner=_Learner(),
                         algorithm=algorithm, writer=writer, steps=25, num_humans=1,
                         t_T=1, t_R=3)
        try:
            for t in range(25):
                row = loop.step(t).row
                order += [r["robot"] for r in row["robots"] if r.get("served") == 0]
        finally:
            loop.close()
    return order


def test_a_priority_by_the_wait_is_a_class_and_a_registry_entry(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(ALGORITHMS, "d", AlgorithmSpec(
        "d", _longest_wait, learns=False, teleop=False,
        description="longest wait first: resets in the order the arms went out"))
    spec = ALGORITHMS["d"]
    assert spec.reads == frozenset() and spec.train_parts == frozenset()
    order = _served_order("d", tmp_path / "d")
    went_out = [ARMS[i] for i in (3, 1, 5, 0, 2)]
    assert order == went_out, order  # first come, first served
    waits: npt.NDArray[np.int64] = np.array([0, 2, 0, 0, 0, 1])
    keys = LongestWaitPriority(len(ARMS)).keys(PrioritySignals(
        t=0, violating=np.array([False, True, False, True, False, True]), waited=waits))
    assert keys[:, 0].tolist() == [0.0, 3.0, 0.0, 1.0, 0.0, 2.0]
