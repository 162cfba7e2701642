"""``testbed rehearse --faults``' schedule and drills without a twin: drawn from the run's
seed, every kind in a run of ``MIN_STEPS``, at most one fault per host, a fault cleared
after its delay, the next one on a host only once its arms are back."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from testbed.lab.fault_drills import (
    FAULT_KINDS,
    FAULTS_FILE,
    MIN_STEPS,
    FaultDrills,
    PlannedFault,
    fault_schedule,
)

HOSTS = {"yumi-a": ["left", "right"], "yumi-b": ["left", "right"]}


def test_the_schedule_is_the_seeds_and_has_every_kind_in_a_run_of_min_steps() -> None:
    a = fault_schedule(5, 30, HOSTS)
    assert a == fault_schedule(5, 30, HOSTS)  # reproducible
    assert a != fault_schedule(6, 30, HOSTS)
    assert MIN_STEPS <= 30
    for seed in range(20):
        s = fault_schedule(seed, MIN_STEPS, HOSTS)
        assert sorted(f.kind for f in s) == sorted(FAULT_KINDS)
        steps = [f.step for f in s]
        assert steps == sorted(steps) and len(set(steps)) == len(steps)
        assert steps[0] >= 2 and steps[-1] + 2 < MIN_STEPS - 1
        assert all(f.arm in HOSTS[f.host] and f.held in (1, 2) for f in s)
    assert 0 < len(fault_schedule(0, 15, HOSTS)) < len(FAULT_KINDS)
    assert fault_schedule(0, 5, HOSTS) == []


class FakeLab:
    """The lab's hands, recorded: the twins' /lab/fault and /lab/clear, the sshds."""

    def __init__(self) -> None:
        self.done: list[tuple[str, str, str]] = []
        self.hosts = {h: SimpleNamespace(lab=self._twin(h), sshd=self._sshd(h)) for h in HOSTS}

    def record_pids(self) -> None:
        """The lab's pid file after an sshd restart (nothing to record here)."""

    def _twin(self, host: str) -> Any:
        def fault(kind: str, arm: str | None = None) -> dict[str, Any]:
            self.done.append(("fault", host, kind))
            return {"shows": f"{kind} shown"}

        def clear(kind: str) -> dict[str, Any]:
            self.done.append(("clear", host, kind))
            return {"actions": [f"cleared {kind}"]}

        return SimpleNamespace(fault=fault, clear=clear)

    def _sshd(self, host: str) -> Any:
        return SimpleNamespace(stop=lambda: self.done.append(("fault", host, "link_lost")),
                               start=lambda: self.done.append(("clear", host, "link_lost")))


def row(modes: dict[str, str]) -> dict[str, Any]:
    return {"robots": [{"robot": f"{h}/{a}", "mode": modes.get(h, "autonomous")}
                       for h in HOSTS for a in HOSTS[h]]}


def test_drills_clear_after_the_delay_and_wait_for_the_arms_before_the_next_fault(
        tmp_path: Path) -> None:
    plan = [PlannedFault(2, 1, "guard_stop", "yumi-a", "left"),
            PlannedFault(3, 2, "link_lost", "yumi-a", "right"),
            PlannedFault(3, 1, "rapid_error", "yumi-b", "right")]
    lab = FakeLab()
    said: list[str] = []
    drills = FaultDrills(lab, plan, tmp_path, 30, said.append)  # type: ignore[arg-type]
    drills.after_step(0, row({}))
    assert lab.done == []  # not before its step
    drills.after_step(1, row({}))
    assert lab.done == [("fault", "yumi-a", "guard_stop")]
    drills.after_step(2, row({"yumi-a": "fault"}))  # held 1 step: cleared before step 3
    assert lab.done[1:] == [("clear", "yumi-a", "guard_stop"),
                            ("fault", "yumi-b", "rapid_error")]  # yumi-a's arms not back yet
    drills.after_step(3, row({"yumi-a": "fault", "yumi-b": "fault"}))  # still not back
    assert lab.done[3:] == [("clear", "yumi-b", "rapid_error")]
    drills.after_step(4, row({}))  # both back: the link may go now
    assert lab.done[4:] == [("fault", "yumi-a", "link_lost")]
    drills.end()  # the run ended with it active: the person clears it
    assert lab.done[5:] == [("clear", "yumi-a", "link_lost")]
    assert sum(line.startswith("FAULT ") for line in said) == 3
    rows = [json.loads(x) for x in (tmp_path / FAULTS_FILE).read_text().splitlines()]
    assert [(r["kind"], r["step"], r["cleared"], r["seen"]) for r in rows] == [
        ("guard_stop", 2, 3, 2), ("rapid_error", 3, 4, 3), ("link_lost", 5, None, None)]


def test_a_stop_no_arm_showed_is_held_until_one_does_or_three_steps_more(
        tmp_path: Path) -> None:
    plan = [PlannedFault(2, 1, "guard_stop", "yumi-a", "left"),
            PlannedFault(2, 1, "motors_off", "yumi-b", "left")]
    lab = FakeLab()
    drills = FaultDrills(lab, plan, tmp_path, 30, lambda _: None)  # type: ignore[arg-type]
    drills.after_step(1, row({}))  # yumi-a at work: its guard stop goes in
    assert lab.done == [("fault", "yumi-a", "guard_stop")]
    drills.after_step(2, row({"yumi-a": "idle"}))  # due, but no arm asked: still there
    assert lab.done[1:] == [("fault", "yumi-b", "motors_off")]
    drills.after_step(3, row({"yumi-a": "idle", "yumi-b": "fault"}))  # yumi-b's showed
    assert lab.done[2:] == [("clear", "yumi-b", "motors_off")]
    drills.after_step(4, row({"yumi-a": "fault"}))  # yumi-a pushed, met it: cleared
    assert lab.done[3:] == [("clear", "yumi-a", "guard_stop")]
    rows = {r["kind"]: r for r in (json.loads(x) for x in
                                   (tmp_path / FAULTS_FILE).read_text().splitlines())}
    assert (rows["guard_stop"]["seen"], rows["guard_stop"]["cleared"]) == (4, 5)
    late = FaultDrills(FakeLab(), plan[:1], tmp_path / "x", 30,
                       lambda _: None)  # type: ignore[arg-type]
    (tmp_path / "x").mkdir()
    for t in range(1, 5):  # never shown: cleared MAX_POSTPONE steps after it was due
        late.after_step(t, row({"yumi-a": "idle"} if t > 1 else {}))
        assert late.active, t
    late.after_step(5, row({"yumi-a": "idle"}))
    assert not late.active and late.lab.done[-1] == ("clear", "yumi-a", "guard_stop")


def _drive(drills: FaultDrills, steps: range, rows: dict[int, dict[str, Any]]) -> None:
    """Each step's row as the arms would show it (a host with a fault active: both its
    arms ``fault``), then the drills between it and the next."""
    for t in steps:
        if t not in rows:
            rows[t] = {"t": t, **row({h: "fault" for h in drills.active})}
        drills.after_step(t, rows[t])


def test_a_resumed_run_replays_its_drills_puts_the_active_fault_back_and_writes_each_once(
        tmp_path: Path) -> None:
    """A rehearsal killed after step 5's checkpoint landed, whose drills had already run
    after step 6 (faults.jsonl has a row of a step the checkpoint dropped): the resumed
    drills, on a fresh lab, end with the same faults.jsonl as a run never killed, the
    fault active at the checkpoint is injected again before the first resumed step, and
    nothing the killed session did before the checkpoint is done again."""
    plan = [PlannedFault(2, 2, "guard_stop", "yumi-a", "left"),
            PlannedFault(3, 1, "rapid_error", "yumi-b", "right"),
            PlannedFault(5, 2, "motors_off", "yumi-b", "left"),
            PlannedFault(9, 1, "link_lost", "yumi-a", "left")]
    whole, killed, resumed = tmp_path / "whole", tmp_path / "killed", tmp_path / "resumed"
    for d in (whole, killed, resumed):
        d.mkdir()
    rows: dict[int, dict[str, Any]] = {}
    ref = FaultDrills(FakeLab(), plan, whole, 14, lambda _: None)  # type: ignore[arg-type]
    _drive(ref, range(12), rows)
    ref.end()
    first = FaultDrills(FakeLab(), plan, killed, 14, lambda _: None)  # type: ignore[arg-type]
    _drive(first, range(7), rows)  # after step 6's drills: killed (its checkpoint: 5)
    (resumed / FAULTS_FILE).write_bytes((killed / FAULTS_FILE).read_bytes())
    lab = FakeLab()
    said: list[str] = []
    again = FaultDrills(lab, plan, resumed, 14, said.append)  # type: ignore[arg-type]
    before_first_step = again.resume([rows[t] for t in range(6)])
    assert lab.done == []  # the replay touches nothing
    before_first_step()  # motors off on yumi-b (before 5, held 2) is still there
    assert lab.done == [("fault", "yumi-b", "motors_off")]
    assert [x for x in said if "still there after the restart" in x]
    _drive(again, range(6, 12), rows)
    again.end()

    def key(d: Path) -> list[tuple[Any, ...]]:
        got = [json.loads(x) for x in (d / FAULTS_FILE).read_text().splitlines()]
        return sorted((r["step"], r["kind"], r["host"], r["cleared"], r["seen"],
                       tuple(r["actions"])) for r in got)

    assert key(resumed) == key(whole)
    assert len(key(resumed)) == len(plan)
    assert lab.done == [("fault", "yumi-b", "motors_off"), ("clear", "yumi-b", "motors_off"),
                        ("fault", "yumi-a", "link_lost"), ("clear", "yumi-a", "link_lost")]
