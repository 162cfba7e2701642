"""The allocator's edges that scripts/mutation.sh found untested (docs/notes/tests.md).

Why: testbed/fleet/allocator.py decides who helps which arm, and its state is what a
crashed trial resumes from. A mutation run showed changes no test noticed: t_T / t_R by
kind (``min_steps``), freeing one human leaving the others on their arms, a freed
human's recorded state, and each consistency check of a checkpoint taken alone (an arm
index equal to the fleet's size, a negative served or waited count, a list of the wrong
length, a checkpoint without waits).
"""

from __future__ import annotations

import json
import re
from typing import Any

import numpy as np
import pytest

from testbed.core.types import InterventionKind
from testbed.fleet.allocator import GAIN_TOLERANCE, Allocator, _jsonable


def busy_allocator() -> Allocator:
    """3 arms, 2 humans, t_T 2, t_R 3: human 0 teleops arm 2, human 1 resets arm 0."""
    alloc = Allocator(3, 2, min_teleop_steps=2, hard_reset_steps=3, seed=0)
    alloc.step(np.array([1.0, 0.0, 2.0]), np.array([True, False, False]))
    assert alloc.assignment.tolist() == [1, -1, 0]
    return alloc


def test_min_steps_is_t_teleop_for_a_teleop_and_t_reset_for_a_reset() -> None:
    alloc = Allocator(2, 1, min_teleop_steps=4, hard_reset_steps=7)
    assert alloc.min_steps(InterventionKind.TELEOP) == 4
    assert alloc.min_steps("teleop") == 4
    assert alloc.min_steps(InterventionKind.RESET) == 7
    assert alloc.min_steps("reset") == 7


def test_releasing_one_arm_leaves_the_other_human_where_it_is() -> None:
    alloc = busy_allocator()
    alloc.step(np.array([1.0, 0.0, 2.0]), np.array([True, False, False]))
    assert alloc.release(2) == 0
    assert alloc.assignment.tolist() == [1, -1, -1]
    assert alloc.held_kinds() == [(InterventionKind.RESET, 1), (None, 0), (None, 0)]
    state = alloc.state_dict()
    assert state["human_arm"] == [-1, 0]
    assert state["human_kind"] == [None, "reset"]
    assert state["human_served"] == [0, 1]
    # the freed state is a valid checkpoint
    Allocator(3, 2, min_teleop_steps=2, hard_reset_steps=3).load_state_dict(state)


def test_release_human_records_the_human_as_free() -> None:
    alloc = busy_allocator()
    alloc.step(np.array([1.0, 0.0, 2.0]), np.array([True, False, False]))
    assert alloc.release_human(1) == 0
    state = alloc.state_dict()
    assert (state["human_arm"], state["human_kind"], state["human_served"]) == \
        ([2, -1], ["teleop", None], [1, 0])


def _state() -> dict[str, Any]:
    state: dict[str, Any] = json.loads(json.dumps(busy_allocator().state_dict()))
    return state


def _load(state: dict[str, Any]) -> Allocator:
    alloc = Allocator(3, 2, min_teleop_steps=2, hard_reset_steps=3)
    alloc.load_state_dict(state)
    return alloc


def test_another_version_is_named_in_the_error() -> None:
    state = _state() | {"version": 2}
    with pytest.raises(ValueError, match=r"^allocator state version 2 is not 1$"):
        _load(state)


@pytest.mark.parametrize("patch", [
    {"human_arm": [2, 3]},                                  # arm index == num_robots
    {"human_arm": [2, -2], "human_kind": ["teleop", None]},  # below -1, kinds fine
    {"human_served": [0, -1]},                              # a negative served count
    {"arm_waited": [0, -1, 0]},                             # a negative wait
    {"human_kind": ["teleop", None]},                       # a busy human with no kind
])
def test_each_inconsistency_alone_is_refused(patch: dict[str, list[Any]]) -> None:
    state = _state()
    fine = state | {"human_kind": patch.get("human_kind", state["human_kind"])}
    fine["human_arm"] = [2, -1] if patch.get("human_kind") == ["teleop", None] else \
        fine["human_arm"]
    _load(fine)  # the same state without the one bad value loads
    with pytest.raises(ValueError, match=r"^allocator state is inconsistent \(arms, kinds, "
                                         r"served, waited\)$"):
        _load(state | patch)


@pytest.mark.parametrize(("field", "value"), [
    ("human_arm", [2, 0, -1]),
    ("human_kind", ["teleop", "reset", None]),
    ("human_served", [0, 0, 0]),
    ("arm_waited", [0, 0, 0, 0]),
])
def test_a_list_of_the_wrong_length_is_refused(field: str, value: list[Any]) -> None:
    state = _state()
    state[field] = value
    with pytest.raises(ValueError):
        _load(state)


def test_a_checkpoint_without_waits_starts_every_wait_at_zero() -> None:
    state = _state()
    state["arm_waited"] = [2, 5, 1]
    assert _load(state).waited.tolist() == [2, 5, 1]
    del state["arm_waited"]
    loaded = _load(state)
    assert loaded.waited.tolist() == [0, 0, 0]
    assert loaded.assignment.tolist() == [1, -1, 0]


def test_a_bad_rng_state_is_named() -> None:
    state = _state() | {"rng": {"bit_generator": "PCG64", "state": "nope"}}
    with pytest.raises(ValueError, match=r"^allocator state: bad RNG state \("):
        _load(state)


def test_gains_that_are_not_numbers_are_a_value_error_naming_the_shape() -> None:
    alloc = Allocator(2, 1, 1, 1, seed=0)
    with pytest.raises(ValueError, match=re.escape("gains must be a float array (M, N): ")):
        alloc.step(np.ones(2), np.zeros(2, dtype=bool), gains=[["a", "b"]])


def test_rng_states_become_plain_json_types() -> None:
    got = _jsonable({"a": (np.int64(3), [np.float32(0.5), "x"]), 1: {"b": np.uint64(7)}})
    assert got == {"a": [3, [0.5, "x"]], "1": {"b": 7}}
    assert type(got["a"][0]) is int and type(got["a"][1][0]) is float
    assert type(got["1"]["b"]) is int


def test_gains_of_the_wrong_shape_or_not_finite_are_named() -> None:
    alloc = Allocator(2, 1, 1, 1, seed=0)
    keys, viol = np.ones(2), np.zeros(2, dtype=bool)
    with pytest.raises(ValueError, match=re.escape(
            "gains must have shape (1, 2) (humans x arms), got (2, 2)")):
        alloc.step(keys, viol, gains=np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"^gains must be finite \(no NaN or infinity\)$"):
        alloc.step(keys, viol, gains=[[0.0, np.inf]])


def test_a_remote_human_keeping_its_teleop_arm_leaves_the_arm_above_to_another() -> None:
    """All remote, equal gains: on the top arm the two free humans tie; the one whose own
    arm is also among the top F (a keeper) gives way, and keeps its own arm after."""
    alloc = Allocator(2, 2, 1, 1, seed=0, on_site=np.array([False, False]))
    viol = np.zeros(2, dtype=bool)
    alloc.step(np.array([0.0, 1.0]), viol, available=np.array([True, False]))
    assert alloc.assignment.tolist() == [-1, 0]
    alloc.step(np.array([2.0, 1.0]), viol)
    assert alloc.assignment.tolist() == [1, 0]
    assert alloc.held_kinds() == [(InterventionKind.TELEOP, 0), (InterventionKind.TELEOP, 1)]


def test_an_on_site_owner_gives_its_teleop_arm_to_a_remote_one_for_a_later_reset() -> None:
    """h1 (on site) owned arm 1's teleop; arm 2 violates and comes later in key order. One
    on-site person left and one reset to come: the remote h2 takes arm 1, h1 resets arm 2."""
    alloc = Allocator(3, 3, 1, 1, seed=0, on_site=np.array([False, True, False]))
    alloc.step(np.array([0.0, 1.0, 0.0]), np.zeros(3, dtype=bool),
               available=np.array([False, True, False]))
    assert alloc.assignment.tolist() == [-1, 1, -1]
    alloc.step(np.array([3.0, 2.0, 1.0]), np.array([False, False, True]))
    assert alloc.assignment.tolist() == [0, 2, 1]
    assert alloc.kinds == [InterventionKind.TELEOP, InterventionKind.TELEOP,
                           InterventionKind.RESET]


def test_a_reset_two_places_down_still_counts_against_the_on_site_owner() -> None:
    """The same rule with the reset right after the owner's arm and more arms after it:
    the violating candidates still to come are counted over every later position."""
    alloc = Allocator(4, 2, 1, 1, seed=0, on_site=np.array([True, False]))
    alloc.step(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(4, dtype=bool),
               available=np.array([True, False]))
    assert alloc.assignment.tolist() == [0, -1, -1, -1]
    alloc.step(np.array([4.0, 3.0, 2.0, 1.0]), np.array([False, True, False, False]))
    assert alloc.assignment.tolist() == [1, 0, -1, -1]
    assert alloc.kinds[:2] == [InterventionKind.TELEOP, InterventionKind.RESET]


def test_a_remote_human_keeps_its_own_top_arm_over_another_remote_one() -> None:
    alloc = Allocator(2, 2, 1, 1, seed=0, on_site=np.array([False, False]))
    viol = np.zeros(2, dtype=bool)
    alloc.step(np.array([1.0, 0.0]), viol, available=np.array([True, False]))
    assert alloc.assignment.tolist() == [0, -1]
    alloc.step(np.array([2.0, 1.0]), viol)
    assert alloc.assignment.tolist() == [0, 1]
    assert alloc.served.tolist() == [1, 0]


def test_a_best_gain_of_minus_the_tolerance_is_still_a_teleop() -> None:
    """Only a best gain *below* -GAIN_TOLERANCE leaves a teleop candidate autonomous."""
    alloc = Allocator(2, 1, 1, 1, seed=0)
    keys, viol = np.array([2.0, 1.0]), np.zeros(2, dtype=bool)
    assert alloc.step(keys, viol, gains=[[-GAIN_TOLERANCE, 0.0]]).tolist() == [0, -1]
    alloc = Allocator(2, 1, 1, 1, seed=0)
    assert alloc.step(keys, viol, gains=[[-2 * GAIN_TOLERANCE, 0.0]]).tolist() == [-1, 0]


def test_a_human_left_free_by_a_step_has_served_0_in_the_checkpoint() -> None:
    alloc = Allocator(2, 2, 1, 1, seed=0)
    alloc.step(np.array([1.0, 0.0]), np.zeros(2, dtype=bool))
    state = alloc.state_dict()
    assert (state["human_arm"], state["human_kind"], state["human_served"]) == (
        [0, -1], ["teleop", None], [0, 0])
    alloc.step(np.array([0.0, 0.0]), np.zeros(2, dtype=bool))  # the teleop ends: t_T = 1
    state = alloc.state_dict()
    assert (state["human_arm"], state["human_served"]) == ([-1, -1], [0, 0])


@pytest.mark.parametrize(("args", "want"), [
    ((2, -1, 1, 1), "num_humans must be >= 0, got -1"),
    ((2, 1, 0, 1), "min_teleop_steps must be >= 1, got 0"),
    ((2, 1, 1, 0), "hard_reset_steps must be >= 1, got 0"),
    ((0, 1, 1, 1), "num_robots must be >= 1, got 0"),
])
def test_a_bad_constructor_argument_is_named(args: tuple[int, int, int, int], want: str
                                             ) -> None:
    with pytest.raises(ValueError, match=f"^{re.escape(want)}$"):
        Allocator(*args)


def test_the_places_are_read_only() -> None:
    alloc = Allocator(2, 2, 1, 1, on_site=np.array([True, False]))
    assert not alloc.on_site.flags.writeable
    with pytest.raises(ValueError):
        alloc.on_site[1] = True


def test_keys_of_the_wrong_shape_name_the_shape_given() -> None:
    with pytest.raises(ValueError, match=re.escape(
            "keys must have shape (2, K) with K >= 1, got (3,)")):
        Allocator(2, 1, 1, 1).step([1.0, 2.0, 3.0], np.zeros(2, dtype=bool))


def test_a_fresh_allocator_has_nobody_on_any_arm() -> None:
    alloc = Allocator(3, 2, 2, 3, seed=0)
    state = alloc.state_dict()
    assert (state["human_arm"], state["human_kind"], state["human_served"],
            state["arm_waited"], state["steps"]) == ([-1, -1], [None, None], [0, 0],
                                                      [0, 0, 0], 0)
