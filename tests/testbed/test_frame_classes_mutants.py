"""Frame classes' edges that scripts/mutation.sh found untested (docs/notes/tests.md).

Why: testbed/records/frame_classes.py derives what learning by class weights and what
exports store; a mutation run showed changes no test noticed: the stored codes' types,
a run of one frame, an empty run, a run whose first step is not 0, the error messages,
a goal coordinate at 0 that jitters below the tolerance, an episode whose cube is still
out when the records stop, the counts by name, and the learner's feed of robot pushes.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from test_frame_classes_records import (
    G1,
    GOAL_CHANGE,
    NO,
    OPEN,
    PI,
    SUCCESS,
    VIOLATION,
    R,
    T,
    auto,
    frames_of,
    step,
    teleop,
)

from testbed.records.frame_classes import ClassTracker, LabelFeed, classify


def test_the_codes_are_int8_int8_int32_from_classify_and_the_tracker() -> None:
    plan = [auto(), auto(success=True), auto()]
    c = classify(frames_of(plan), 1, 3)
    assert (c.classes.dtype, c.outcomes.dtype, c.episodes.dtype) == (np.int8, np.int8,
                                                                     np.int32)
    empty = classify(frames_of(plan)[:0], 1, 3)
    for got in (empty.classes, empty.outcomes, empty.episodes):
        assert got.shape == (0,)
    assert (empty.classes.dtype, empty.outcomes.dtype, empty.episodes.dtype) == (
        np.int8, np.int8, np.int32)
    settled = ClassTracker(1, 3).push(frames_of([auto(success=True)]))
    assert len(settled) == 1
    part = settled[0]
    assert (part.classes.dtype, part.outcomes.dtype, part.episodes.dtype) == (
        np.int8, np.int8, np.int32)


def test_a_run_of_one_frame_is_classified() -> None:
    c = classify(frames_of([auto(success=True)]), 1, 3)
    assert (c.classes.tolist(), c.outcomes.tolist(), c.episodes.tolist()) == (
        [R], [SUCCESS], [0])


def test_a_run_whose_first_step_is_not_0_is_classified_in_place() -> None:
    frames = frames_of([auto(), teleop()], [auto(success=True), auto()])
    frames["t"] += 5  # a run read from step 5 on
    c = classify(frames, 2, 3)
    assert c.classes.tolist() == [PI, R, T, R]
    assert c.outcomes.tolist() == [OPEN, SUCCESS, OPEN, OPEN]
    assert c.episodes.tolist() == [0, 0, 0, 1]


def test_the_errors_name_what_is_wrong() -> None:
    with pytest.raises(ValueError, match=r"^3 frames are not whole steps of 2 arms$"):
        classify(frames_of([auto(), auto(), auto()]), 2, 3)
    with pytest.raises(ValueError, match=r"^pre_steps must be >= 0, got -1$"):
        ClassTracker(1, -1)
    with pytest.raises(ValueError, match=re.escape("a step is 2 frames, got 1")):
        ClassTracker(2, 3).push(frames_of([auto()]))


def test_a_goal_at_0_that_moves_less_than_the_tolerance_is_the_same_goal() -> None:
    near = (5e-7, G1[1])  # x = 0 then 5e-7: within GOAL_TOLERANCE (1e-6)
    plan = [auto(goal=(0.0, G1[1])), auto(goal=near), auto(goal=(0.5, G1[1]))]
    c = classify(frames_of(plan), 1, 3)
    assert c.outcomes.tolist() == [GOAL_CHANGE, GOAL_CHANGE, OPEN]
    assert c.episodes.tolist() == [0, 0, 1]


def test_an_episode_whose_cube_is_out_when_the_records_stop_is_a_violation() -> None:
    plan = [auto(), auto(violation=True), step("idle", goal=G1)]
    c = classify(frames_of(plan), 1, 3)
    assert c.outcomes.tolist() == [VIOLATION] * 3
    assert c.classes.tolist() == [R, R, NO]


def test_counts_name_every_class_and_outcome() -> None:
    plan = [auto(), teleop(), auto(success=True), step("idle")]
    counts = classify(frames_of(plan), 1, 3).counts()
    assert counts == {
        "classes": {"demo": 0, "robot": 1, "teleop": 1, "reset": 0,
                    "pre_intervention": 1, "none": 1},
        "outcomes": {"open": 1, "success": 3, "violation": 0, "goal_change": 0,
                     "unknown": 0},
    }


class Sink:
    """A learner's ``add_robot``, recording what it is handed."""

    def __init__(self) -> None:
        self.calls: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []

    def add_robot(self, images: np.ndarray, actions: np.ndarray, classes: np.ndarray,
                  outcomes: np.ndarray) -> None:
        self.calls.append((images, actions, classes, outcomes))


def test_the_feed_hands_the_robots_pushes_of_each_ended_episode() -> None:
    # one arm: push 0 (ROBOT, later PI), a teleop, push 2 then a refused step (no
    # action: not handed) and a success; then a push whose episode is still open
    plan = [auto(0), teleop(0, 1), auto(2), step("refused", None, None), auto(3, success=True),
            auto(1)]
    frames = frames_of(plan)
    frames["image"][:, 0, 0, 0] = np.arange(len(frames), dtype=frames["image"].dtype) + 10
    feed, sink = LabelFeed(1, 3), Sink()
    for t in range(len(frames)):
        feed.step(sink, frames[t : t + 1])
    assert len(sink.calls) == 1
    images, actions, classes, outcomes = sink.calls[0]
    assert actions.dtype == np.int64 and actions.tolist() == [0, 2, 3]
    assert classes.tolist() == [PI, R, R]
    assert outcomes.tolist() == [SUCCESS] * 3
    assert images[:, 0, 0, 0].tolist() == [10, 12, 14]


def test_a_feed_caught_up_hands_only_what_ends_after() -> None:
    plan = [auto(0), auto(1), auto(2, success=True), auto(3), auto(0, success=True)]
    frames = frames_of(plan)
    feed, sink = LabelFeed(1, 0), Sink()
    feed.catch_up(frames[t : t + 1] for t in range(2))  # given before a resume
    for t in range(2, len(frames)):
        feed.step(sink, frames[t : t + 1])
    assert [c[1].tolist() for c in sink.calls] == [[0, 1, 2], [3, 0]]
