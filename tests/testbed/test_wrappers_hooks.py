"""The explicit wrapper bases, the hooks' chaining and the typed step record.

Why: the wrappers replaced hand-written ``__getattr__`` pass-throughs (an evaluation's
expert, a rehearsal's truth recorder and lab hand), ``TrialHooks`` replaced loose
callbacks, and ``StepRecord`` is the one source of a step's row and frames. Each is
checked here on its own, with small doubles: every call of the contract reaches the
inner object, nothing outside the contract passes silently, and the two written forms
of a step say the same thing.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from testbed.core.hosts import Hosts, LoopHosts
from testbed.core.humans import Humans, Presence, presence_of
from testbed.core.types import (
    IMAGE_SIZE,
    ArmObservation,
    FleetStatus,
    HumanRequest,
    HumanResponse,
    Mode,
    PushResult,
)
from testbed.core.wrappers import HostsWrapper, HumansWrapper
from testbed.experiments.hooks import HookList, TrialHooks, as_hooks
from testbed.records.run_dir import RunDir
from testbed.records.step_record import ArmStep, StepRecord
from testbed.records.steps import validate_step
from testbed.records.store import FRAME_DTYPE, MODES


class _Hosts:
    def __init__(self) -> None:
        self.robot_names = ["h/a"]
        self.calls: list[tuple[str, Any]] = []

    def start(self) -> None:
        self.calls.append(("start", None))

    def observe(self) -> dict[str, ArmObservation]:
        self.calls.append(("observe", None))
        img = np.zeros((IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8)
        return {"h/a": ArmObservation("h/a", img, False, (0.5, 0.5))}

    def execute(self, pushes: Mapping[str, int], resets: Collection[str]
                ) -> dict[str, PushResult]:
        self.calls.append(("execute", (dict(pushes), list(resets))))
        return {"h/a": PushResult("h/a", pushes.get("h/a"), True, False)}

    def rest(self) -> None:
        self.calls.append(("rest", None))

    def reseed(self, trial_seed: int) -> None:
        self.calls.append(("reseed", trial_seed))

    def close(self) -> None:
        self.calls.append(("close", None))

    def frame(self, host: str) -> None:  # not in the contract
        raise AssertionError("never reached through a wrapper")


class _AwayHumans:
    def __init__(self) -> None:
        self.calls: list[str] = []

    def act(self, requests: Sequence[HumanRequest], t: int) -> dict[str, HumanResponse]:
        self.calls.append(f"act {t}")
        return {}

    def show(self, t: int, status: FleetStatus) -> None:
        self.calls.append(f"show {t}")

    def presence(self) -> Presence:
        return Presence(np.array([True, False]), frozenset({1}))

    def close(self) -> None:
        self.calls.append("close")


class _PresentHumans(_AwayHumans):
    presence = None  # type: ignore[assignment]  # humans who are never away


def test_hosts_wrapper_forwards_every_call_of_the_contract_and_nothing_else() -> None:
    inner = _Hosts()
    wrapped = HostsWrapper(HostsWrapper(inner))
    assert isinstance(wrapped, Hosts) and isinstance(wrapped, LoopHosts)
    assert wrapped.robot_names == ["h/a"] and wrapped.unwrapped is inner
    wrapped.start()
    assert list(wrapped.observe()) == ["h/a"]
    assert wrapped.execute({"h/a": 2}, [])["h/a"].action == 2
    wrapped.reseed(7)
    wrapped.rest()
    wrapped.close()
    assert inner.calls == [("start", None), ("observe", None), ("execute", ({"h/a": 2}, [])),
                           ("reseed", 7), ("rest", None), ("close", None)]
    with pytest.raises(AttributeError):
        wrapped.frame("h")  # type: ignore[attr-defined]


def test_humans_wrapper_forwards_presence_whether_or_not_the_inner_humans_can_be_away(
) -> None:
    away = _AwayHumans()
    wrapped = HumansWrapper(away)
    assert isinstance(wrapped, Humans)
    p = presence_of(wrapped)
    assert p is not None and p.gone == frozenset({1}) and p.available.tolist() == [True, False]
    assert presence_of(HumansWrapper(_PresentHumans())) is None
    wrapped.act([], 3)
    wrapped.show(3, FleetStatus(t=3, steps=5))
    wrapped.close()
    assert away.calls == ["act 3", "show 3", "close"]


class _Recorder(TrialHooks):
    def __init__(self, name: str, log: list[str], humans: Humans | None = None,
                 handles: bool = False) -> None:
        self.name, self.log, self._humans, self.handles = name, log, humans, handles

    def before_run(self, name: str) -> bool:
        self.log.append(f"{self.name} before {name}")
        return self.handles

    def humans(self, name: str) -> Humans | None:
        return self._humans

    def wrap_hosts(self, hosts: Hosts, run: RunDir) -> Hosts:
        self.log.append(f"{self.name} wraps")
        return HostsWrapper(hosts)

    def on_phase(self, name: str, done: int, total: int) -> None:
        self.log.append(f"{self.name} {name} {done}/{total}")

    def on_step(self, outcome: Any) -> None:
        self.log.append(f"{self.name} step {outcome}")


def test_hook_list_calls_every_hook_in_order_and_composes_the_wrappers(tmp_path: Path
                                                                          ) -> None:
    log: list[str] = []
    humans = _AwayHumans()
    hooks = HookList([_Recorder("a", log), None, _Recorder("b", log, humans, handles=True)])
    assert hooks.before_run("cur-t0") is True  # one hook put the cubes back: no prompt
    assert hooks.humans("cur-t0") is humans
    inner = _Hosts()
    hosts = hooks.wrap_hosts(inner, RunDir(tmp_path))
    assert isinstance(hosts, HostsWrapper) and hosts.unwrapped is inner
    assert isinstance(hosts.hosts, HostsWrapper)  # b's wrapper around a's
    hooks.on_phase("collect", 1, 2)
    hooks.on_step("t0")
    assert log == ["a before cur-t0", "b before cur-t0", "a wraps", "b wraps",
                   "a collect 1/2", "b collect 1/2", "a step t0", "b step t0"]
    plain = as_hooks()
    assert plain.before_run("x") is False and plain.humans("x") is None
    assert plain.wrap_hosts(inner, RunDir(tmp_path)) is inner
    one = _Recorder("c", log)
    assert as_hooks(None, one) is one


def _record() -> StepRecord:
    images = np.arange(2 * IMAGE_SIZE * IMAGE_SIZE * 3, dtype=np.uint8).reshape(
        2, IMAGE_SIZE, IMAGE_SIZE, 3)
    arms = [ArmStep("h/a", Mode.TELEOP, 0, 3, True, False, 0.25, 0.5, (0.0, 0.25, 0.5)),
            ArmStep("h/b", Mode.FAULT, None, None, False, False, None, None, (0.0, 0.0, 0.0))]
    return StepRecord(7, 1, arms, images, np.array([True, False]),
                      np.array([[0.5, 0.4], [np.nan, np.nan]], np.float32),
                      faults={"h/b": "host down"}, away=[1],
                      released=[{"robot": "h/a", "human": 1, "why": "away"}],
                      wall_time=1.7e9, duration_s=0.5)


def test_a_step_record_writes_one_step_as_a_valid_row_and_the_same_frames() -> None:
    record = _record()
    row = record.to_row()
    validate_step(row)
    assert list(row) == ["t", "robots", "faults", "away", "released", "wall_time",
                         "duration_s"]
    assert row["robots"][0] == {"robot": "h/a", "mode": "teleop", "human": 0, "action": 3,
                                "success": True, "violation": False, "uncertainty": 0.25,
                                "risk": 0.5, "key": [0.0, 0.25, 0.5]}
    frames = record.to_frames()
    assert frames.dtype == FRAME_DTYPE and len(frames) == 2
    assert frames["t"].tolist() == [7, 7] and frames["session"].tolist() == [1, 1]
    assert [MODES[m] for m in frames["mode"]] == ["teleop", "fault"]
    assert frames["human"].tolist() == [0, -1] and frames["action"].tolist() == [3, -1]
    assert np.isnan(frames["uncertainty"][1]) and frames["risk"][0] == np.float32(0.5)
    assert (frames["image"] == record.images).all() and frames["wall_time"][0] == 1.7e9
    again = StepRecord.from_row(row, 1, record.images, record.observed, record.goals)
    assert again.to_row() == row
    assert again.to_frames().tobytes() == frames.tobytes()


def test_a_row_without_away_humans_or_faults_has_no_such_keys() -> None:
    record = _record()
    record.faults, record.away, record.released = {}, [], []
    assert list(record.to_row()) == ["t", "robots", "wall_time", "duration_s"]
