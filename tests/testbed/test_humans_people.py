"""The humans as people: per-human counts from the records, scripted profiles that
differ (skill, latency, availability), and the step row's ``served`` / ``first``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from testbed.core.types import ArmObservation, HumanRequest, InterventionKind
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.fleet.interventions import FirstActions
from testbed.people.people_config import HumanProfile
from testbed.records.steps import RecordError, validate_step
from testbed.results.report_humans import count_humans, merge

IMG = np.zeros((64, 64, 3), np.uint8)


def _arm(robot: str, mode: str, human: int | None = None, served: int | None = None,
         first: tuple[int, float | None] | None = None, action: int | None = 1,
         success: bool = False, violation: bool = False) -> dict[str, Any]:
    row: dict[str, Any] = {"robot": robot, "mode": mode, "human": human,
                           "action": None if mode == "reset" else action,
                           "success": success, "violation": violation,
                           "uncertainty": 0.1, "risk": 0.0, "key": [0.0]}
    if served is not None:
        row["served"] = served
    if first is not None:
        row["first"] = {"steps": first[0], "s": first[1]}
    return row


A, T, R = "autonomous", "teleop", "reset"


def _record() -> list[dict[str, Any]]:
    """Two arms, two humans, 6 steps; counted by hand in the test below."""
    rows = [
        # t0: human 0 starts a teleop on a and lets the step pass; b is autonomous
        [_arm("a", T, 0, 0, action=None), _arm("b", A)],
        # t1: human 0 pushes (first push after 1 step, 0.8 s), success; human 1 starts
        #     a reset on b
        [_arm("a", T, 0, 1, (1, 0.8), success=True), _arm("b", R, 1, 0)],
        # t2: human 0 pushes again (violation: the arm goes to a reset, a new one);
        #     human 1 confirms b's reset (2 steps)
        [_arm("a", T, 0, 2, violation=True), _arm("b", R, 1, 1, (1, 0.5))],
        # t3: human 0 resets a (a new intervention, kind changed); human 1 teleops b at
        #     once (first push after 0 steps)
        [_arm("a", R, 0, 0), _arm("b", T, 1, 0, (0, 0.2))],
        # t4: human 0 confirms after 2 steps; human 1 pushes, a success (its only one)
        [_arm("a", R, 0, 1, (1, None)), _arm("b", T, 1, 1, success=True)],
        # t5: human 1 starts a new teleop on a the step after (served 0 again); b auto
        [_arm("a", T, 1, 0, (0, 1.5)), _arm("b", A)],
    ]
    return [{"t": t, "robots": r} for t, r in enumerate(rows)]


def test_per_human_counts_equal_a_hand_count() -> None:
    rows = _record()
    for row in rows:
        validate_step(row)
    h0, h1 = count_humans(rows, 2)
    # human 0: teleop at t0-t2, reset at t3-t4
    assert (h0.teleops, h0.resets, h0.steps_held) == (1, 1, 5)
    assert (h0.pushes, h0.successes, h0.violations) == (2, 1, 1)
    assert h0.first_push_steps == [1] and h0.first_push_s == [0.8]
    assert h0.reset_steps == [2]
    # human 1: reset of b at t1-t2, teleop of b at t3-t4, teleop of a at t5
    assert (h1.teleops, h1.resets, h1.steps_held) == (2, 1, 5)
    assert (h1.pushes, h1.successes, h1.violations) == (3, 1, 0)
    assert h1.first_push_steps == [0, 0] and h1.first_push_s == [0.2, 1.5]
    assert h1.reset_steps == [2]
    both = merge([h0, h1])
    assert (both.teleops, both.pushes, both.success_rate) == (3, 5, 2 / 5)


def test_records_without_served_count_interventions_where_the_human_changes() -> None:
    rows = _record()
    for row in rows:
        for r in row["robots"]:
            r.pop("served", None)
            r.pop("first", None)
    h0, h1 = count_humans(rows, 2)
    # the kind change (teleop -> reset) still starts an intervention; t5's new teleop
    # of a by human 1 differs in human from t4's: counted too
    assert (h0.teleops, h0.resets) == (1, 1)
    assert (h1.teleops, h1.resets) == (2, 1)
    assert h0.first_push_steps == []


def test_the_row_schema_checks_served_and_first() -> None:
    bad = {"t": 0, "robots": [_arm("a", A, None, 0)]}
    with pytest.raises(RecordError, match="served"):
        validate_step(bad)
    bad = {"t": 0, "robots": [_arm("a", T, 0, 2, (1, 0.3))]}
    with pytest.raises(RecordError, match="first"):
        validate_step(bad)


def test_first_actions_marks_one_step_per_intervention_and_survives_a_resume() -> None:
    f = FirstActions()
    assert [f.first("a", s, acted) for s, acted in
            [(0, False), (1, True), (2, True), (0, True), (1, True)]] == [
        False, True, False, True, False]
    g = FirstActions()  # resumed after t1 of the first intervention
    g.restore([{"robots": [{"robot": "a", "served": 0}]},
               {"robots": [{"robot": "a", "served": 1, "first": {"steps": 1, "s": 0}}]}])
    assert g.first("a", 2, True) is False


def _request(robot: str, human: int, kind: InterventionKind, served: int,
             expert: int = 2, min_steps: int = 3) -> HumanRequest:
    obs = ArmObservation(robot, IMG, False, (0.5, 0.5), expert_action=expert)
    return HumanRequest(robot, human, kind, obs, served, min_steps)


def test_a_latency_delays_the_first_push_and_the_reset() -> None:
    humans = ScriptedHumans([HumanProfile(name="slow", latency=2)], robots=["a"])
    teleop = [humans.act([_request("a", 0, InterventionKind.TELEOP, s)], s)["a"]
              for s in range(4)]
    assert [r.action for r in teleop] == [None, None, 2, 2]
    # their time to act is in steps (the row's first.steps); no seconds: the twin's
    # speed is not the human's, and seconds would make two runs of one seed differ
    assert all(r.waited_s is None for r in teleop)
    reset = [humans.act([_request("a", 0, InterventionKind.RESET, s, min_steps=3)], s)["a"]
             for s in range(5)]
    assert [r.reset_done for r in reset] == [False, False, False, False, True]  # t_R + 2


def test_availability_is_drawn_per_step_and_seed_and_replays() -> None:
    profiles = [HumanProfile(name="ana", availability=0.5), HumanProfile(name="bo")]
    a = ScriptedHumans(profiles, seed=4)
    b = ScriptedHumans(profiles, seed=4)
    seen = [a.presence_at(t) for t in range(200)]
    assert all(p is not None and p.available[1] for p in seen)  # bo is always there
    there = np.array([p.available[0] for p in seen if p is not None])
    assert 0.35 < there.mean() < 0.65
    # a resumed trial draws what the uninterrupted one drew, step by step
    assert [b.presence_at(t).available.tolist() for t in (150, 3, 77)] == [  # type: ignore[union-attr]
        seen[t].available.tolist() for t in (150, 3, 77)]  # type: ignore[union-attr]
    assert ScriptedHumans([HumanProfile(name="c")]).presence_at(0) is None


def _success_per_push(skill: float, seed: int, steps: int = 60) -> tuple[float, int]:
    """Both arms of a real twin cell teleoperated by one scripted human for ``steps``
    steps (hard resets at once): successes per push and the number of pushes."""
    from sim_twin.cell import TwinCell

    humans = ScriptedHumans([HumanProfile(name="h", skill=skill)], seed=seed,
                            robots=["left", "right"])
    pushes = successes = 0
    with TwinCell(seed=seed) as cell:
        for t in range(steps):
            reqs = []
            for arm in cell.arm_names:
                if cell.arm_state(arm).violating:
                    cell.hard_reset(arm)
                obs = ArmObservation(arm, IMG, False, (0.5, 0.5),
                                     expert_action=cell.expert_action(arm))
                reqs.append(HumanRequest(arm, 0, InterventionKind.TELEOP, obs, t, 3))
            answers = humans.act(reqs, t)
            out = cell.push({arm: int(a.action) for arm, a in answers.items()
                             if a.action is not None})
            pushes += len(out)
            successes += sum(o.success for o in out.values())
    return successes / pushes, pushes


@pytest.mark.slow
def test_a_less_skilled_scripted_human_succeeds_less_per_push_than_the_spread() -> None:
    rates = {(skill, seed): _success_per_push(skill, seed)
             for skill in (1.0, 0.5) for seed in (0, 1)}
    assert all(n >= 100 for _, n in rates.values())
    expert = [rates[(1.0, s)][0] for s in (0, 1)]
    half = [rates[(0.5, s)][0] for s in (0, 1)]
    spread = max(abs(expert[0] - expert[1]), abs(half[0] - half[1]))
    assert np.mean(expert) - np.mean(half) > spread, rates
    assert max(half) < min(expert), rates


def test_people_in_the_config_name_the_humans(tmp_path: Path) -> None:
    from testbed.people.people_config import HumansConfig

    h = HumansConfig.model_validate({"people": [{"name": "ana", "skill": 0.5},
                                                {"name": "bo"}]})
    assert h.count == 2 and h.names == ["ana", "bo"]
    assert HumansConfig(count=3).names == ["human0", "human1", "human2"]


def test_each_person_is_on_site_or_remote_for_every_kind() -> None:
    """``where`` (issue 44): on site by default (old configs unchanged), remote for any
    kind, scripted ones too (the twin rehearses a lab's split); with humans, someone is
    on site, or the config names ``people`` and says why and how to fix it."""
    from testbed.core.config import ConfigError
    from testbed.experiments.fleet_config import parse_config
    from testbed.people.people_config import HumansConfig

    assert HumansConfig(count=3).on_site == [True, True, True]
    assert HumanProfile(name="ana").where == "on_site"
    for kind in ("scripted", "gui", "web"):
        h = HumansConfig.model_validate({"kind": kind, "people": [
            {"name": "ana"}, {"name": "bo", "where": "remote"}]})
        assert h.on_site == [True, False] and h.places == ["on_site", "remote"]
    with pytest.raises(ConfigError) as caught:
        parse_config({"humans": {"people": [{"name": "ana", "where": "remote"}]}})
    line = str(caught.value)
    assert line.startswith("config: humans.people: nobody is on site"), line
    assert "hard reset needs a person in the room" in line and "\n" not in line
    assert 'where = "on_site"' in line
    assert HumansConfig(count=0).on_site == []  # no humans: nobody to ask for


def test_a_reset_addressed_to_a_remote_scripted_human_is_done_by_one_on_site() -> None:
    """The allocator never sends one; the data collection before a trial addresses its
    resets by arm index: the reset is then done as the on-site profile does it (here
    ana's 2 steps of latency), never by the remote one (bo, instant)."""
    from testbed.core.humans import reset_taker

    humans = ScriptedHumans([HumanProfile(name="ana", latency=2),
                             HumanProfile(name="bo", where="remote")], robots=["a"])
    obs = ArmObservation("a", IMG, violating=True, goal=(0.5, 0.5), expert_action=0)
    for served, done in ((0, False), (1, False), (2, True)):
        req = HumanRequest("a", 1, InterventionKind.RESET, obs, served=served, min_steps=1)
        assert humans.act([req], 0)["a"].reset_done is done
    places = ["remote", "on_site", "remote", "on_site"]
    assert [reset_taker(h, places) for h in range(5)] == [1, 1, 1, 3, 4]
    assert reset_taker(0, []) == 0 and reset_taker(0, ["remote"]) == 0
