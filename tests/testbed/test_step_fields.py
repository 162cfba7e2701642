"""Every field of a step reaches every place it must: the checklist "A new field in every
step" of docs/ARCHITECTURE.md, as tests.

Why: a step is written twice (a steps.jsonl row, one data-store frame per arm) from one
``StepRecord``, read back by resume and the tools, and exported. A field added to one of
those places and forgotten in another is silent: the row validates (rows are
extensible), the frame is zeros. These tests fail on the place forgotten: an ``ArmStep``
field missing from the row or not read back, a frame field with no source in the
record, a field in neither the frames nor the list of row-only fields, a layout changed
without its format version (``test_rundata.py``), a store field the export drops or
does not fill (``test_export.py``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from testbed.core.types import IMAGE_SIZE, Mode
from testbed.records.step_record import ArmStep, StepRecord
from testbed.records.steps import validate_step
from testbed.records.store import FRAME_DTYPE, FRAME_READINGS, MODES

ROW_ONLY = {
    "robot": "the frame's arm index says which arm",
    "key": "the priority keys: as many as the algorithm has, a row's list",
    "refused": "the host's reason, text",
    "served": "an intervention's count, derived again from the modes by the tools",
    "first": "the human's response time, per intervention",
    "monitor": "the failure monitor's scores beyond uncertainty and risk: a run's own set",
    "waited": "the allocator's wait count, its bookkeeping: derived again from the rows",
    "readings": "what the robot host measured of the push, by name: a backend's own set "
                "(one that is a column too is a FRAME_DTYPE field named in FRAME_READINGS)",
}
"""``ArmStep`` fields kept only in steps.jsonl, and why. A new field goes either into
``FRAME_DTYPE`` or here, on purpose."""

STEP_FIELDS = {"t", "arm", "session", "observed", "goal", "wall_time", "image"}
"""Frame fields filled from the ``StepRecord`` (the step's), not from its ``ArmStep``."""


def full_arm() -> ArmStep:
    """An arm step with every field set to a value that is not its default."""
    return ArmStep("left", Mode.REFUSED, 1, 2, True, False, 0.25, 0.5, (3.0, -1.0),
                   refused="the controller is in guard stop", served=4, first=(4, 1.5),
                   monitor={"novelty": 0.125, "goal_risk": 0.75},
                   readings={"push_s": 1.75} | dict.fromkeys(FRAME_READINGS, 2.5))


def waiting_arm() -> ArmStep:
    """An arm with no human, waiting for one: the fields only such an arm has set."""
    return ArmStep("right", Mode.IDLE, None, None, False, False, 0.125, 0.25, (1.0,),
                   waited=3)


def test_every_arm_field_is_in_the_row_it_validates_and_it_reads_back() -> None:
    arms = [full_arm(), waiting_arm()]  # an arm with a human, and one waiting for one
    fields = {f.name for f in dataclasses.fields(ArmStep)}
    assert all(any(getattr(arm, f) != f_default for arm in arms) for f, f_default in
               ((f.name, f.default) for f in dataclasses.fields(ArmStep))
               if f_default is not dataclasses.MISSING), "the two arms set every field"
    assert set(arms[0].to_entry()) | set(arms[1].to_entry()) == fields
    images = np.zeros((2, IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8)
    record = StepRecord(7, 0, arms, images, np.ones(2, bool), np.zeros((2, 2), np.float32),
                        wall_time=12.5, duration_s=0.75)
    row = record.to_row()
    validate_step(row)
    back = StepRecord.from_row(row, 0, images, np.ones(2, bool), np.zeros((2, 2), np.float32))
    assert back.arms == arms
    assert (back.t, back.wall_time, back.duration_s) == (7, 12.5, 0.75)


def test_every_arm_field_is_a_frame_field_or_row_only_and_every_frame_field_is_filled() -> None:
    arm_fields = {f.name for f in dataclasses.fields(ArmStep)}
    frame_fields = set(FRAME_DTYPE.names or ())
    undecided = arm_fields - frame_fields - set(ROW_ONLY)
    assert not undecided, f"ArmStep fields in neither FRAME_DTYPE nor ROW_ONLY: {undecided}"
    assert set(FRAME_READINGS) <= frame_fields, "a reading made a column needs its field"
    sourceless = frame_fields - arm_fields - STEP_FIELDS - set(FRAME_READINGS)
    assert not sourceless, f"FRAME_DTYPE fields nothing fills: {sourceless}"
    # and to_frames fills them: every frame field differs from the zeros it starts from
    arm = dataclasses.replace(full_arm(), mode=Mode.TELEOP, refused=None, success=True,
                              violation=True)
    images = np.full((1, IMAGE_SIZE, IMAGE_SIZE, 3), 9, np.uint8)
    frame = StepRecord(7, 2, [dataclasses.replace(arm, robot="right"), arm],
                       np.concatenate([images, images]), np.ones(2, bool),
                       np.full((2, 2), 0.5, np.float32), wall_time=12.5).to_frames()[1]
    zero = np.zeros((), FRAME_DTYPE)
    unfilled = {n for n in frame_fields if np.array_equal(frame[n], zero[n])}
    assert not unfilled, f"to_frames leaves these at zero: {unfilled}"
    assert MODES[frame["mode"]] == "teleop" and frame["human"] == 1 and frame["action"] == 2
