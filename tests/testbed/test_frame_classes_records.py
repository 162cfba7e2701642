"""Every frame's class and its episode's outcome on hand-built records (issue 30, item 1).

Each case is a short plan per arm (mode, human, action, success, violation, goal,
session), turned into the data store's frames; the expected classes and outcomes are
written out by hand from the rules of ``testbed/records/frame_classes.py``. Then: the
incremental tracker settles every frame of a long random run exactly once and agrees
with ``classify`` and with an independent reading of the rules written here; and a run
read back (``run_classes``) from its data store, from steps.jsonl alone (no store), or
from a store whose layout lacks a field, says what it could not derive.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from testbed.core.types import MAX_PUSHES_PER_GOAL, EpisodeOutcome, FrameClass
from testbed.records.frame_classes import DEFAULT_PRE_STEPS, ClassTracker, classify
from testbed.records.run_classes import LABEL_DTYPE, pre_steps_of, run_classes
from testbed.records.step_record import StepRecord
from testbed.records.steps import RunWriter
from testbed.records.store import FRAME_DTYPE, MODES, RunData, RunDataWriter

R, T, RS, PI, NO = (FrameClass.ROBOT, FrameClass.TELEOP, FrameClass.RESET,
                    FrameClass.PRE_INTERVENTION, FrameClass.NONE)
OPEN, SUCCESS, VIOLATION, GOAL_CHANGE, UNKNOWN = (
    EpisodeOutcome.OPEN, EpisodeOutcome.SUCCESS, EpisodeOutcome.VIOLATION,
    EpisodeOutcome.GOAL_CHANGE, EpisodeOutcome.UNKNOWN)
G1, G2, G3 = (0.2, 0.3), (0.7, 0.6), (0.4, 0.8)


def step(mode: str, human: int | None = None, action: int | None = None, *,
         success: bool = False, violation: bool = False,
         goal: tuple[float, float] | None = G1, session: int = 0) -> dict[str, Any]:
    """One arm's step; ``goal`` None: not observed (a fault)."""
    return {"mode": mode, "human": human, "action": action, "success": success,
            "violation": violation, "goal": goal, "session": session}


def auto(action: int = 0, **kw: Any) -> dict[str, Any]:
    return step("autonomous", None, action, **kw)


def teleop(human: int = 0, action: int | None = 1, **kw: Any) -> dict[str, Any]:
    return step("teleop", human, action, **kw)


def frames_of(*arms: list[dict[str, Any]]) -> np.ndarray:
    """The plans (one list per arm, equal lengths) as step-major store frames."""
    n = len(arms)
    out = np.zeros(len(arms[0]) * n, FRAME_DTYPE)
    for t in range(len(arms[0])):
        for a, plan in enumerate(arms):
            s, f = plan[t], out[t * n + a : t * n + a + 1]
            f["t"], f["arm"], f["session"] = t, a, s["session"]
            f["mode"] = MODES.index(s["mode"])
            f["human"] = -1 if s["human"] is None else s["human"]
            f["action"] = -1 if s["action"] is None else s["action"]
            f["success"], f["violation"] = s["success"], s["violation"]
            f["observed"] = s["goal"] is not None
            f["goal"] = (np.nan, np.nan) if s["goal"] is None else s["goal"]
    return out


def one_arm(plan: list[dict[str, Any]], k: int = 3) -> tuple[list[int], list[int], list[int]]:
    c = classify(frames_of(plan), 1, k)
    return c.classes.tolist(), c.outcomes.tolist(), c.episodes.tolist()


# ----------------------------------------------------------------- hand-built cases
def test_a_window_that_would_start_before_the_run_is_cut_at_step_0() -> None:
    plan = [auto(), auto(), teleop(), teleop(), auto()]
    assert one_arm(plan, k=3)[0] == [PI, PI, T, T, R]
    assert one_arm(plan, k=1)[0] == [R, PI, T, T, R]
    assert one_arm(plan, k=0)[0] == [R, R, T, T, R]  # k = 0: no pre-intervention


def test_a_window_crosses_a_resume_only_when_the_episode_goes_on() -> None:
    same = [auto(), auto(), auto(), auto(), auto(session=1), teleop(session=1)]
    classes, outcomes, episodes = one_arm(same, k=3)
    assert classes == [R, R, PI, PI, PI, T]  # steps 2..4: across the resume, same goal
    assert episodes == [0] * 6 and outcomes == [OPEN] * 6
    moved = [auto(), auto(), auto(), auto(), auto(goal=G2, session=1),
             teleop(goal=G2, session=1)]
    classes, outcomes, episodes = one_arm(moved, k=3)
    assert classes == [R, R, R, R, PI, T]  # a new world: the window stops at its start
    assert episodes == [0, 0, 0, 0, 1, 1]
    assert outcomes == [OPEN] * 6  # cut by the resume: OPEN, and the last one still runs


def test_a_violation_keeps_its_wait_and_reset_and_the_reset_is_a_takeover() -> None:
    plan = [auto(), auto(), auto(violation=True), step("idle"), step("reset", 1),
            step("reset", 1), auto(goal=G2), auto(goal=G2, success=True), auto(goal=G3)]
    classes, outcomes, episodes = one_arm(plan, k=3)
    # the reset at step 4 is a takeover: steps 1..3 (the violating push among them)
    assert classes == [R, PI, PI, NO, RS, RS, R, R, R]
    assert outcomes == [VIOLATION] * 6 + [SUCCESS] * 2 + [OPEN]
    assert episodes == [0] * 6 + [1, 1, 2]


def test_a_goal_change_a_fault_that_hid_the_end_and_an_open_end() -> None:
    plan = [auto(), auto(), auto(goal=G2), step("fault", goal=None),
            step("refused", goal=G3), auto(goal=G3), teleop(action=None, goal=G3),
            auto(goal=G3)]
    classes, outcomes, episodes = one_arm(plan)
    assert outcomes == [GOAL_CHANGE] * 2 + [UNKNOWN] * 2 + [OPEN] * 4
    assert episodes == [0, 0, 1, 1, 2, 2, 2, 2]
    # a fault, a refused push and a teleop step the human let pass: nobody acted; the
    # takeover at step 6 reaches back into its own episode only (step 5)
    assert classes == [R, R, R, NO, NO, PI, NO, R]


def test_the_arms_are_apart_and_a_handover_between_humans_is_no_takeover() -> None:
    a0 = [auto(), auto(), teleop(0), teleop(1), auto()]
    a1 = [auto(), teleop(1), auto(), auto(), auto(success=True)]
    c = classify(frames_of(a0, a1), 2, 3)
    assert c.classes[0::2].tolist() == [PI, PI, T, T, R]
    assert c.classes[1::2].tolist() == [PI, T, R, R, R]
    assert c.outcomes[1::2].tolist() == [SUCCESS] * 5


def test_a_reset_confirmed_early_still_ends_its_episode_as_a_violation() -> None:
    """The allocator holds a reset t_R steps (docs/notes/core.md, rule 2) even when the
    person confirms sooner: the frames after the confirmation are mode reset with the
    new goal. The violated episode ended in a violation, whatever came after."""
    plan = [auto(), auto(violation=True), step("reset", 0), step("reset", 0, goal=G2),
            step("reset", 0, goal=G2), auto(goal=G2)]
    _, outcomes, episodes = one_arm(plan)
    assert outcomes[:3] == [VIOLATION] * 3 and episodes[:3] == [0, 0, 0]


# ----------------------------------------------------------------- tracker == classify
def random_run(rng: np.random.Generator, steps: int, arms: int) -> np.ndarray:
    """Any mix of what the records hold: every mode, humans coming and going, pushes,
    successes, violations, goals that change, faults, resumes."""
    f = np.zeros(steps * arms, FRAME_DTYPE)
    goals = rng.integers(0, 3, arms)
    tail = np.zeros(arms, bool)  # after a violation, while idle, reset or fault
    session = 0
    for t in range(steps):
        session += rng.random() < 0.02
        for a in range(arms):
            r = f[t * arms + a : t * arms + a + 1]
            mode = int(rng.choice(len(MODES), p=[0.55, 0.2, 0.07, 0.08, 0.05, 0.05]))
            tail[a] &= MODES[mode] in ("idle", "reset", "fault")
            r["t"], r["arm"], r["session"], r["mode"] = t, a, session, mode
            r["human"] = rng.integers(0, 2) if MODES[mode] in ("teleop", "reset") else (
                rng.integers(-1, 2) if MODES[mode] == "fault" else -1)
            pushes = MODES[mode] in ("autonomous", "teleop") and rng.random() < 0.9
            r["action"] = rng.integers(0, 4) if pushes else -1
            r["success"] = pushes and rng.random() < 0.08
            r["violation"] = pushes and not r["success"][0] and rng.random() < 0.05
            if rng.random() < 0.05 and not tail[a]:  # (a goal seen during a reset:
                goals[a] = rng.integers(0, 3)         # test_a_reset_confirmed...)
            tail[a] |= bool(r["violation"][0])
            r["observed"] = MODES[mode] != "fault"
            r["goal"] = (0.1 * goals[a], 0.5) if r["observed"][0] else (np.nan, np.nan)
    return f


def reference(frames: np.ndarray, arms: int, k: int) -> tuple[np.ndarray, ...]:
    """The rules read again, differently: first every episode's bounds and outcome
    from the whole arm at once, then the classes and the windows."""
    n = len(frames)
    classes = np.zeros(n, np.int8)
    outcomes = np.zeros(n, np.int8)
    episodes = np.zeros(n, np.int32)
    m = {name: MODES.index(name) for name in MODES}
    for a in range(arms):
        idx = np.arange(a, n, arms)
        f = frames[idx]
        bounds: list[tuple[int, int, int]] = []  # (first, last, outcome)
        start, i = 0, 0
        while start < len(f):
            end, outcome, seen = len(f) - 1, OPEN, None  # seen: last observed index
            i = start
            while i < len(f):
                if f["observed"][i]:  # a new goal ends the episode before this frame
                    if seen is not None and not np.allclose(f["goal"][i], f["goal"][seen]):
                        end = i - 1
                        outcome = (OPEN if f["session"][i] != f["session"][seen] else
                                   UNKNOWN if i - seen > 1 else GOAL_CHANGE)
                        break
                    seen = i
                if f["success"][i]:
                    end, outcome = i, SUCCESS
                    break
                if f["violation"][i]:  # its wait, reset and faults belong to it
                    j = i + 1
                    while j < len(f) and f["mode"][j] in (m["idle"], m["reset"], m["fault"]):
                        j += 1
                    end, outcome = j - 1, VIOLATION
                    break
                i += 1
            bounds.append((start, end, outcome))
            start = end + 1
        for e, (lo, hi, outcome) in enumerate(bounds):
            outcomes[idx[lo:hi + 1]] = outcome
            episodes[idx[lo:hi + 1]] = e
            for i in range(lo, hi + 1):
                mode, act = f["mode"][i], f["action"][i]
                classes[idx[i]] = (R if mode == m["autonomous"] and act >= 0 else
                                   T if mode == m["teleop"] and act >= 0 else
                                   RS if mode == m["reset"] else NO)
            for i in range(lo, hi + 1):
                if f["human"][i] >= 0 and (i == 0 or f["human"][i - 1] < 0):
                    for j in range(max(lo, i - k), i):
                        if f["t"][j] >= f["t"][i] - k and classes[idx[j]] == R:
                            classes[idx[j]] = PI
    return classes, outcomes, episodes


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_tracker_settles_every_frame_once_as_classify_and_the_rules_say(seed: int) -> None:
    rng = np.random.default_rng(seed)
    arms, steps, k = 3, 600, int(rng.integers(1, 6))
    frames = random_run(rng, steps, arms)
    tracker = ClassTracker(arms, k)
    settled = []
    for t in range(steps):
        settled += tracker.push(frames[t * arms:(t + 1) * arms])
        assert all(int(p.frames["t"].max()) <= t for p in settled)
    settled += tracker.flush()
    assert tracker.flush() == []  # flushed: nothing left
    got = np.concatenate([p.frames for p in settled])
    at = got["t"].astype(np.int64) * arms + got["arm"]
    assert sorted(at.tolist()) == list(range(steps * arms))  # each frame exactly once
    for p in settled:  # one arm's one episode, in step order
        assert len(set(p.frames["arm"].tolist())) == 1 and len(set(p.episodes.tolist())) == 1
        assert len(set(p.outcomes.tolist())) == 1 and np.all(np.diff(p.frames["t"]) > 0)
    c = classify(frames, arms, k)
    for name in ("classes", "outcomes", "episodes"):
        mine = np.zeros(steps * arms, getattr(c, name).dtype)
        mine[at] = np.concatenate([getattr(p, name) for p in settled])
        assert np.array_equal(mine, getattr(c, name)), name
    want = reference(frames, arms, k)
    assert np.array_equal(c.episodes, want[2])
    assert np.array_equal(c.outcomes, want[1])
    assert np.array_equal(c.classes, want[0])
    # every kind of episode end and class happened, so the comparison covers them
    assert set(c.outcomes.tolist()) == set(map(int, EpisodeOutcome))
    assert set(c.classes.tolist()) == set(map(int, FrameClass)) - {FrameClass.DEMO}


# ----------------------------------------------------------------- read back from a run
A0 = [auto(), auto(), teleop(0), teleop(0), auto(success=True), auto(goal=G2),
      auto(goal=G2, violation=True), step("idle", goal=G2), step("reset", 1, goal=G2),
      auto(goal=G3), auto(goal=G3)]
A1 = [auto(goal=G3), step("fault", goal=None), auto(goal=G3), step("refused", goal=G3),
      teleop(1, goal=G3), auto(goal=G3), auto(goal=G3), auto(goal=G3), auto(goal=G3),
      auto(goal=G3), auto(goal=G3)]
ROBOTS = ["c/left", "c/right"]


def write_run(run: Path, plans: tuple[list[dict[str, Any]], ...], *, store: bool = True,
              resume_at: int | None = None, config: str | None = None) -> np.ndarray:
    """A run folder with these plans: steps.jsonl, run.json, config.toml, and (``store``)
    its data store; resumed at ``resume_at`` (run.json ``resumed``, frames' session)."""
    run.mkdir(parents=True)
    frames = frames_of(*plans)
    n = len(plans)
    data = RunDataWriter(run, ROBOTS[:n]) if store else None
    resumed = []
    with RunWriter(run) as w:
        for t in range(len(plans[0])):
            f = frames[t * n:(t + 1) * n]
            wall = 1.7e9 + 10.0 * t
            if resume_at is not None and t == resume_at:
                resumed.append(wall - 1.0)
            f["session"] = len(resumed)
            f["wall_time"] = wall
            row = {"t": t, "robots": [], "wall_time": wall, "duration_s": 1.0}
            for a in range(n):
                p = plans[a][t]
                row["robots"].append({
                    "robot": ROBOTS[a], "mode": p["mode"], "human": p["human"],
                    "action": p["action"], "success": p["success"],
                    "violation": p["violation"],
                    "uncertainty": None if p["goal"] is None else 0.1,
                    "risk": None if p["goal"] is None else 0.2, "key": [0.0]})
                if p["mode"] == "refused":
                    row["robots"][-1]["refused"] = "cube not found"
            rec = StepRecord.from_row(row, len(resumed), np.zeros((n, 64, 64, 3), np.uint8),
                                      f["observed"], f["goal"])
            if data is not None:
                data.append(rec.to_frames())
            w.write_step(row)
            frames[t * n:(t + 1) * n] = f
    if data is not None:
        data.close()
    (run / "run.json").write_text(json.dumps({"options": {"algorithm": "cur"},
                                              "resumed": resumed}))
    if config is not None:
        (run / "config.toml").write_text(config)
    return frames


def test_a_run_reads_back_from_its_store_with_its_own_k(tmp_path: Path) -> None:
    frames = write_run(tmp_path / "r", (A0, A1), config="[learning]\n"
                       "pre_intervention_steps = 1\n")
    rc = run_classes(tmp_path / "r")
    assert rc.source == "data store" and rc.notes == [] and rc.pre_steps == 1
    want = classify(frames, 2, 1)
    assert np.array_equal(rc.classes.classes, want.classes)
    assert rc.classes.classes[0::2].tolist() == [R, PI, T, T, R, R, R, NO, RS, R, R]
    assert rc.class_counts() == {"demo": 0, "robot": 14, "teleop": 3, "reset": 1,
                                 "pre_intervention": 1, "none": 3}
    # episodes, not frames: arm 0 success, violation, open; arm 1 one open episode
    assert rc.outcome_counts() == {"open": 2, "success": 1, "violation": 1,
                                   "goal_change": 0, "unknown": 0}
    assert rc.frames.dtype == LABEL_DTYPE
    assert run_classes(tmp_path / "r", pre_steps=3).classes.classes[0::2].tolist()[:2] == [PI, PI]
    assert len(run_classes(tmp_path / "r", steps=4).frames) == 8


def test_a_run_without_a_store_derives_from_steps_jsonl_and_says_what_it_cannot(
        tmp_path: Path) -> None:
    with_store = write_run(tmp_path / "a", (A0, A1), resume_at=7)
    write_run(tmp_path / "b", (A0, A1), store=False, resume_at=7)
    assert pre_steps_of(tmp_path / "b") == DEFAULT_PRE_STEPS  # no config.toml
    rc = run_classes(tmp_path / "b")
    assert rc.source == "steps.jsonl"
    assert rc.notes[0] == "no data store: classes from steps.jsonl, no images"
    text = " ".join(rc.notes)
    assert "resume is taken as a new goal" in text and "fault is not seen" in text
    assert "timeout" in text  # not a twin fleet: a timeout cannot be placed
    assert list(rc.frames["session"][0::2]) == [0] * 7 + [1] * 4
    store_rc = run_classes(tmp_path / "a")
    assert np.array_equal(store_rc.frames["session"], with_store["session"])
    assert np.array_equal(store_rc.frames["session"], rc.frames["session"])
    # the classes agree; arm 0's episodes too (the resume came while it waited for its
    # reset: that episode still ends as a violation); arm 1 kept its goal across the
    # resume, which the rows cannot know: they cut its episode there, OPEN
    assert np.array_equal(store_rc.classes.classes, rc.classes.classes)
    for name in ("outcomes", "episodes"):
        assert np.array_equal(getattr(store_rc.classes, name)[0::2],
                              getattr(rc.classes, name)[0::2]), name
    assert store_rc.classes.outcomes[0::2].tolist() == [SUCCESS] * 5 + [VIOLATION] * 4 + [OPEN] * 2
    assert store_rc.classes.episodes[1::2].tolist() == [0] * 11
    assert rc.classes.episodes[1::2].tolist() == [0] * 7 + [1] * 4
    assert rc.classes.outcomes[1::2].tolist() == [OPEN] * 11


def test_steps_jsonl_alone_places_the_twins_timeout(tmp_path: Path) -> None:
    """On a twin the goal changes after MAX_PUSHES_PER_GOAL pushes without success; the
    rows have no goal, so the rule places it, and agrees with the store."""
    n = MAX_PUSHES_PER_GOAL
    plan = [auto() for _ in range(n)] + [auto(goal=G2) for _ in range(5)]
    twin = "[[hosts]]\nname = \"cell0\"\n"
    write_run(tmp_path / "store", (plan,), config=twin)
    write_run(tmp_path / "rows", (plan,), store=False, config=twin)
    rows = run_classes(tmp_path / "rows")
    assert "timeout" not in " ".join(rows.notes)
    assert rows.classes.outcomes.tolist() == [GOAL_CHANGE] * n + [OPEN] * 5
    assert np.array_equal(rows.classes.outcomes, run_classes(tmp_path / "store").classes.outcomes)


def test_an_older_store_layout_falls_back_to_the_rows(tmp_path: Path) -> None:
    write_run(tmp_path / "r", (A0, A1))
    folder = tmp_path / "r" / "data"
    data = RunData(folder)
    old = [(n, FRAME_DTYPE.fields[n][0]) for n in FRAME_DTYPE.names if n != "goal"]  # type: ignore[index]
    frames = data.frames()
    slim = np.zeros(len(frames), old)
    for name, _ in old:
        slim[name] = frames[name]
    slim.tofile(folder / "frames-00000.bin")
    meta = json.loads((folder / "meta.json").read_text())
    meta["dtype"] = [d for d in meta["dtype"] if d[0] != "goal"]
    (folder / "meta.json").write_text(json.dumps(meta))
    rc = run_classes(tmp_path / "r")
    assert rc.source == "steps.jsonl"
    assert rc.notes[0] == ("its data store (format testbed.rundata/1) has no goal: classes "
                           "from steps.jsonl, no images")


def test_the_report_counts_each_runs_classes_and_says_where_they_came_from(
        tmp_path: Path) -> None:
    from testbed.results.report import write_report

    write_run(tmp_path / "runs" / "cur-t0", (A0, A1),
              config="[learning]\npre_intervention_steps = 1\n")
    write_run(tmp_path / "runs" / "cur-t1", (A0, A1), store=False)
    rep = write_report([tmp_path / "runs"], tmp_path / "rep")
    table = next(t for t in rep.tables if t.key == "classes")
    # frames: robot, pre-intervention, teleop, reset, none; episodes: success,
    # violation, goal change, unknown, open
    assert table.rows == [
        ["cur-t0", "cur", "1", "14", "1", "3", "1", "3", "1", "1", "0", "0", "2"],
        ["cur-t1", "cur", "3", "10", "5", "3", "1", "3", "1", "1", "0", "0", "2"]]
    assert table.notes == ["cur-t1: no data store: classes from steps.jsonl, no images; "
                           "no goals in steps.jsonl: an end hidden by a fault is not seen "
                           "(no UNKNOWN); an episode ended by a new goal without a success "
                           "(a timeout) runs on into the next"]
    csv = (tmp_path / "rep" / "report-classes.csv").read_text().splitlines()
    assert csv[1].startswith("cur-t0,cur,1,data store,14,1,")
    assert "Frame classes per run" in (tmp_path / "rep" / "report.md").read_text()
