"""Humans who come and go (the web console's away humans) in the fleet loop.

``FleetLoop`` asks ``presence_of(humans)`` before each allocation: an away human gets
no new intervention, a held one goes on until the human is ``gone``, then the arm is
released and the row says so; rows of runs where nobody is away are unchanged. The
humans here are a fake with a scripted away schedule (what ``gui.web.WebHumans``
reports from its pages), the hosts and learner small fakes, so the loop runs in
milliseconds with the real allocator and C.U.R.'s keys.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from types import ModuleType, SimpleNamespace
from typing import Any

import numpy as np
import pytest
from loop_fakes import CalmHosts, QuietLearner

from testbed.core.humans import Humans, Presence, presence_of
from testbed.core.types import (
    FleetStatus,
    HumanRequest,
    HumanResponse,
    InterventionKind,
)
from testbed.experiments.build import make_humans
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import get_algorithm
from testbed.fleet.loop import FleetLoop
from testbed.people.people_config import WebConsoleConfig
from testbed.records.steps import RecordError, RunWriter, read_steps, validate_step

ARMS = ["h/a", "h/b", "h/c"]
M = 2


class _Learner(QuietLearner):
    """Acts with push 2; ``uncertainty(t)`` gives C.U.R.'s u per arm (its keys)."""

    def __init__(self, uncertainty: Callable[[int], list[float]]) -> None:
        self.uncertainty = uncertainty
        self.t = 0

    def act(self, images: np.ndarray) -> Any:
        n = len(images)
        u = np.asarray(self.uncertainty(self.t), dtype=float)
        self.t += 1
        z = np.zeros(n)
        return SimpleNamespace(actions=np.full(n, 2), uncertainty=u, risk=z, goal_risk=z,
                               novelty=z)


class AwayHumans:
    """Scripted answers (the expert's face; a reset done at its t_R-th step) and a
    scripted presence: ``away[t]`` the humans away at step t, ``gone[t]`` those of them
    away past the grace period. ``presence()`` is asked once per step, before ``act``."""

    def __init__(self, away: Mapping[int, set[int]] | None = None,
                 gone: Mapping[int, set[int]] | None = None) -> None:
        self.away = dict(away or {})
        self.gone = dict(gone or {})
        self.asked = 0
        self.requests: dict[int, list[HumanRequest]] = {}
        self.health: dict[int, str] = {}
        """What the consoles were shown of the run's health, per step (issue 44)."""

    def presence(self) -> Presence:
        t = self.asked
        self.asked += 1
        gone = self.gone.get(t, set())
        away = self.away.get(t, set()) | gone
        return Presence(np.array([h not in away for h in range(M)]), frozenset(gone))

    def act(self, requests: Sequence[HumanRequest], t: int) -> dict[str, HumanResponse]:
        assert self.asked == t + 1, "presence() is asked before act(), once per step"
        self.requests[t] = list(requests)
        return ScriptedHumans().act(requests, t)

    def show(self, t: int, status: FleetStatus) -> None:
        self.health[t] = status.health()

    def close(self) -> None:
        return None


def _run(tmp: Path, humans: Humans, steps: int, *, t_T: int,
         uncertainty: Callable[[int], list[float]] = lambda t: [0.9, 0.5, 0.1],
         ) -> list[dict[str, Any]]:
    algorithm = get_algorithm("cur", AlgorithmConfig(t_I=0, u_hat=0.0, t_T=t_T, t_R=2),
                              len(ARMS), M, seed=0)
    tmp.mkdir()
    with RunWriter(tmp) as writer:
        loop = FleetLoop(hosts=CalmHosts(ARMS), humans=humans, learner=_Learner(uncertainty),
                         algorithm=algorithm, writer=writer, steps=steps, num_humans=M,
                         t_T=t_T, t_R=2)
        try:
            for t in range(steps):
                loop.step(t)
        finally:
            loop.close()
    rows = read_steps(tmp)  # validated: away and released included
    for row in rows:
        row.pop("wall_time"), row.pop("duration_s")
    return rows


def _on(row: dict[str, Any]) -> dict[str, int | None]:
    return {r["robot"]: r["human"] for r in row["robots"]}


def test_an_away_human_gets_no_new_request_until_back(tmp_path: Path) -> None:
    humans = AwayHumans(away={t: {1} for t in (2, 3, 4)})
    rows = _run(tmp_path / "run", humans, 7, t_T=1)  # t_T = 1: nobody is ever held long
    for t, row in enumerate(rows):
        asked = {req.human for req in humans.requests[t]}
        if t in (2, 3, 4):
            assert 1 not in asked and row["away"] == [1]
            assert _on(row) == {"h/a": 0, "h/b": None, "h/c": None}
            assert row["robots"][1]["mode"] == "autonomous"
        else:
            assert asked == {0, 1} and "away" not in row
            assert _on(row) == {"h/a": 0, "h/b": 1, "h/c": None}
        assert "released" not in row  # nobody was gone
        # the consoles and the progress line say who is away (issue 44)
        assert ("away: human 1" in humans.health[t]) is (t in (2, 3, 4)), humans.health[t]
    # Back at step 5: a new teleop, served from 0.
    assert [(r.robot, r.served) for r in humans.requests[5] if r.human == 1] == [("h/b", 0)]


def test_a_held_teleop_goes_on_while_away_and_ends_when_gone(tmp_path: Path) -> None:
    # Human 1 teleoperates h/b from step 0 (t_T = 4: held through step 3); its page
    # closes at step 1 and it is gone (past the grace period) from step 2. From step 4
    # h/b has the top key, and human 0, free again, takes it.
    humans = AwayHumans(away={1: {1}}, gone={t: {1} for t in range(2, 7)})
    rows = _run(tmp_path / "run", humans, 7, t_T=4,
                uncertainty=lambda t: [0.9, 0.5, 0.1] if t < 4 else [0.1, 0.9, 0.0])
    held = [r for r in humans.requests[1] if r.human == 1]
    assert [(r.robot, r.kind, r.served) for r in held] == [("h/b", InterventionKind.TELEOP, 1)]
    assert rows[1]["away"] == [1] and "released" not in rows[1]
    assert _on(rows[1]) == {"h/a": 0, "h/b": 1, "h/c": None}
    # Gone: the arm is released before the allocation and the row says so, once.
    assert rows[2]["released"] == [{"robot": "h/b", "human": 1, "why": "away"}]
    assert rows[2]["away"] == [1]
    assert _on(rows[2]) == {"h/a": 0, "h/b": None, "h/c": None}  # human 0 is still held
    assert all(1 not in {r.human for r in humans.requests[t]} for t in range(2, 7))
    assert all("released" not in rows[t] and rows[t]["away"] == [1] for t in range(3, 7))
    # Another (present) human takes the released arm once it is free and h/b leads.
    assert _on(rows[4]) == {"h/a": None, "h/b": 0, "h/c": None}
    assert [(r.robot, r.served) for r in humans.requests[4]] == [("h/b", 0)]


def test_rows_without_away_humans_are_the_rows_of_humans_without_presence(
        tmp_path: Path) -> None:
    present = _run(tmp_path / "present", AwayHumans(), 6, t_T=2)
    scripted = _run(tmp_path / "scripted", ScriptedHumans(), 6, t_T=2)
    assert presence_of(ScriptedHumans()) is None
    assert present == scripted
    assert all("away" not in row and "released" not in row for row in present)
    assert {r["mode"] for row in present for r in row["robots"]} == {"teleop", "autonomous"}


def test_a_presence_that_does_not_fit_the_fleet_is_a_clear_error(tmp_path: Path) -> None:
    class Wrong(AwayHumans):
        def presence(self) -> Presence:
            return Presence(np.ones(M + 1, dtype=bool))

    with pytest.raises(ValueError, match=r"available must be bool with shape \(2,\)"):
        _run(tmp_path / "run", Wrong(), 1, t_T=1)


def test_the_new_row_fields_are_validated() -> None:
    row: dict[str, Any] = {"t": 0, "robots": [
        {"robot": "h/a", "mode": "autonomous", "human": None, "action": 1, "success": False,
         "violation": False, "uncertainty": 0.0, "risk": 0.0, "key": [0.0]}]}
    validate_step(row | {"away": [1], "released": [{"robot": "h/a", "human": 1,
                                                     "why": "away"}]})
    for bad, match in (({"away": [-1]}, "away must be"), ({"away": "1"}, "away must be"),
                       ({"released": {}}, "released must be a list"),
                       ({"released": [{"robot": "h/z", "human": 1, "why": "away"}]},
                        r"released\[0\]"),
                       ({"released": [{"robot": "h/a", "human": 1}]}, r"released\[0\]")):
        with pytest.raises(RecordError, match=match):
            validate_step(row | bad)


def test_make_humans_builds_the_web_console_from_its_config(
        monkeypatch: pytest.MonkeyPatch) -> None:
    built: list[tuple[int, WebConsoleConfig]] = []

    class WebHumans(AwayHumans):  # stands in for gui.web.WebHumans (its classmethod)
        @classmethod
        def from_config(cls, count: int, web: WebConsoleConfig,
                        names: Sequence[str] = (), places: Sequence[str] = (),
                        resumed_at: int | None = None) -> WebHumans:
            built.append((count, web))
            return cls()

    fake = ModuleType("gui.web")
    fake.WebHumans = WebHumans  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "gui.web", fake)
    web = WebConsoleConfig(port=0, grace_s=2.0)
    assert isinstance(make_humans("web", 3, web), WebHumans)
    assert isinstance(make_humans("web", 1), WebHumans)
    assert built == [(3, web), (1, WebConsoleConfig())]
    with pytest.raises(ValueError, match="use scripted, gui or web"):
        make_humans("robots", 1)
