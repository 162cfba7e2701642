"""TwinCell: images, determinism, the face-push primitive, and the task semantics."""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterator

import numpy as np
import pytest

import sim_twin
from sim_twin import FACE_DIRECTIONS, TwinCell, TwinOutcome
from sim_twin.constants import (
    CUBE_FRICTION,
    CUBE_MASS_KG,
    GOAL_MARGIN,
    MIN_GOAL_DISTANCE,
    PUSH_BIAS,
    PUSH_JITTER,
    PUSHER_FRICTION,
    RESET_NOISE,
    SUCCESS_RADIUS,
    TABLE_RGB,
)
from sim_twin.geometry import depth_inside, push_direction, reduce_yaw
from testbed.core import types


@pytest.fixture
def cell() -> Iterator[TwinCell]:
    with TwinCell(seed=7) as c:
        yield c


def test_constants_are_the_testbed_contract() -> None:
    assert sim_twin.FACE_DIRECTIONS == types.FACE_DIRECTIONS
    assert sim_twin.SUCCESS_RADIUS == types.SUCCESS_RADIUS
    assert sim_twin.MIN_GOAL_DISTANCE == types.MIN_GOAL_DISTANCE
    assert sim_twin.MAX_PUSHES_PER_GOAL == types.MAX_PUSHES_PER_GOAL
    assert sim_twin.IMAGE_SIZE == types.IMAGE_SIZE
    assert sim_twin.NUM_ACTIONS == types.NUM_ACTIONS


def test_observe_gives_canonical_images(cell: TwinCell) -> None:
    images = cell.observe()
    assert list(images) == ["left", "right"]
    for img in images.values():
        assert img.shape == (64, 64, 3) and img.dtype == np.uint8
        assert img.flags.c_contiguous
    images["left"][:] = 0  # the caller owns its copy
    assert cell.observe()["left"].any()


def test_other_sizes_and_arm_layouts() -> None:
    with TwinCell(1, arms=("a", "b", "c"), mirror=(False, True, False), image_size=32,
                  render_scale=2) as c:
        images = c.observe()
        assert [i.shape for i in images.values()] == [(32, 32, 3)] * 3
        c.push({"b": 0})
    with TwinCell(2, arms=("solo",), mirror=(False,)) as c:
        first = c.observe()["solo"]
        c.set_arm_state("solo", c.arm_state("solo").cube_xy, c.arm_state("solo").yaw,
                        (0.8, 0.2))
        again = c.observe()["solo"]
        assert (first != again).any() and (c.observe()["solo"] == again).all()
    with pytest.raises(ValueError, match="mirror"):
        TwinCell(1, arms=("a",), mirror=(False, True))
    with pytest.raises(ValueError, match="distinct"):
        TwinCell(1, arms=("a", "a"))


def _trace(seed: int, steps: int = 25) -> str:
    h = hashlib.sha256()
    with TwinCell(seed) as c:
        for t in range(steps):
            for img in c.observe().values():
                h.update(img.tobytes())
            faces = {a: (c.expert_action(a) if t % 3 else t % 4) for a in c.arm_names}
            for arm, out in c.push(faces).items():
                h.update(repr(out).encode())
                if out.violation:
                    c.hard_reset(arm)
    return h.hexdigest()


def test_same_seed_same_image_bytes_and_outcomes() -> None:
    first = _trace(11)
    with TwinCell(12) as other:  # another world alive in the same process changes nothing
        other.push({"left": 1, "right": 2})
        assert _trace(11) == first
    assert _trace(12) != first


def test_parameters_vary_per_seed_within_their_ranges() -> None:
    draws = []
    for seed in range(6):
        with TwinCell(seed) as c:
            for arm in c.arm_names:
                p = c.cube_params(arm)
                for value, (lo, hi) in ((p.mass_kg, CUBE_MASS_KG), (p.friction, CUBE_FRICTION),
                                        (p.pusher_friction, PUSHER_FRICTION),
                                        (p.push_bias, PUSH_BIAS), (p.push_jitter, PUSH_JITTER)):
                    assert lo <= value <= hi
                draws.append(p)
    assert len(set(draws)) == len(draws)


def test_each_face_push_moves_the_cube_along_its_face() -> None:
    """Object-centric: face k moves the cube along FACE_DIRECTIONS[k] turned by the
    cube's yaw (so within 45 degrees of FACE_DIRECTIONS[k]), on both arms, the mirrored
    one included, in >= 95% of random states."""
    rng = np.random.default_rng(0)
    along = within = n = 0
    for seed in range(3):
        with TwinCell(seed) as c:
            for _ in range(40):
                before, faces = {}, {}
                for arm in c.arm_names:
                    c.set_arm_state(arm, rng.uniform(0.25, 0.75, 2),
                                    rng.uniform(-math.pi / 4, math.pi / 4), (0.5, 0.5))
                    before[arm] = c.arm_state(arm)
                    faces[arm] = int(rng.integers(4))
                c.push(faces)
                for arm, k in faces.items():
                    d = np.subtract(c.arm_state(arm).cube_xy, before[arm].cube_xy)
                    step = float(np.linalg.norm(d))
                    normal = push_direction(k, before[arm].yaw)
                    angle = math.degrees(math.acos(np.clip(d @ normal / step, -1.0, 1.0)))
                    along += d @ np.asarray(FACE_DIRECTIONS[k]) > 0.05
                    within += angle < 30.0 and 0.06 < step < 0.2
                    n += 1
    assert along / n >= 0.95
    assert within / n >= 0.95


def test_mirrored_arm_swaps_left_and_right_in_the_world(cell: TwinCell) -> None:
    def column_of_right_cube() -> float:
        pic = cell.picture()
        half = pic[:, pic.shape[1] // 2:]
        _, xs = np.nonzero(np.any(half != TABLE_RGB, axis=2))
        return float(xs.mean())

    for face, sign in ((3, -1.0), (1, +1.0)):  # canonical right = world left, mirrored
        cell.set_arm_state("right", (0.5, 0.5), 0.0, (0.1, 0.1))
        x0 = column_of_right_cube()
        cell.push({"right": face})
        assert sign * (column_of_right_cube() - x0) > 3.0


def test_pushers_rest_out_of_view(cell: TwinCell) -> None:
    for face in range(4):
        cell.push({"left": face, "right": (face + 1) % 4})
        pic = cell.picture()
        not_table = np.any(pic != TABLE_RGB, axis=2)
        r, g, b = (pic[..., i].astype(int) for i in range(3))
        orange = (r > g + 40) & (r > b + 40)  # the cube, lit or shaded
        assert not (not_table & ~orange).any()


def test_push_moves_only_the_arms_named(cell: TwinCell) -> None:
    before = cell.arm_state("right")
    cell.push({"left": 2})
    after = cell.arm_state("right")
    assert math.dist(before.cube_xy, after.cube_xy) < 1e-3
    assert after.pushes_since_goal == before.pushes_since_goal


def test_violation_fires_once_blocks_the_arm_until_a_hard_reset(cell: TwinCell) -> None:
    cell.set_arm_state("left", (0.12, 0.5), 0.0, (0.5, 0.5))
    assert not cell.arm_state("left").violating
    out = cell.push({"left": 1, "right": 0})  # left: towards the edge at x = 0.075
    assert out["left"] == TwinOutcome(success=False, violation=True, soft_reset=False)
    assert not out["right"].violation
    state = cell.arm_state("left")
    assert state.violating and depth_inside(state.cube_xy) < 0
    # Refused from now on: nothing moves and no second violation event.
    assert cell.push({"left": 3}) == {"left": TwinOutcome(False, False, False)}
    assert cell.arm_state("left").cube_xy == state.cube_xy
    cell.hard_reset("left")
    state = cell.arm_state("left")
    assert not state.violating and state.pushes_since_goal == 0
    assert max(abs(v - 0.5) for v in state.cube_xy) <= RESET_NOISE + 1e-3
    assert not cell.push({"left": 3})["left"].violation
    assert cell.arm_state("left").cube_xy != state.cube_xy


def test_violation_through_a_cut_corner(cell: TwinCell) -> None:
    # Near the top-left cut (edge x + y = 0.35), inside the square's margins throughout.
    cell.set_arm_state("right", (0.25, 0.25), 0.0, (0.6, 0.6))
    assert depth_inside(cell.arm_state("right").cube_xy) > 0
    assert cell.push({"right": 0})["right"].violation is False  # up: still inside
    assert cell.push({"right": 1})["right"].violation is True  # left: out through the cut


def test_outcomes_follow_the_ground_truth_exactly() -> None:
    """On many constructed states near goal and edge, each outcome is exactly what the
    ground truth after the push says (success within SUCCESS_RADIUS of the goal, violation
    outside WORKSPACE_POLYGON)."""
    rng = np.random.default_rng(1)
    seen = {"success": 0, "violation": 0, "neither": 0}
    with TwinCell(3) as c:
        for _ in range(60):
            faces, goals = {}, {}
            for arm in c.arm_names:
                xy = rng.uniform(0.05, 0.95, 2)
                k = int(rng.integers(4))
                yaw = float(rng.uniform(-math.pi / 4, math.pi / 4))
                goal = xy + 0.106 * push_direction(k, yaw) + rng.normal(0, 0.07, 2)
                c.set_arm_state(arm, xy, yaw, goal, pushes_since_goal=3)
                faces[arm], goals[arm] = k, c.arm_state(arm)
            for arm, out in c.push(faces).items():
                before, after = goals[arm], c.arm_state(arm)
                if before.violating:
                    assert out == TwinOutcome(False, False, False)
                    continue
                outside = depth_inside(after.cube_xy) < 0
                reached = not outside and math.dist(after.cube_xy, before.goal_xy) <= SUCCESS_RADIUS
                assert out.violation == outside and after.violating == outside
                assert out.success == reached and out.soft_reset == reached
                if reached:
                    assert after.pushes_since_goal == 0
                    assert math.dist(after.goal_xy, after.cube_xy) >= MIN_GOAL_DISTANCE
                    assert depth_inside(after.goal_xy) >= GOAL_MARGIN
                else:
                    assert after.goal_xy == before.goal_xy
                    assert after.pushes_since_goal == (3 if outside else 4)
                seen["success" if reached else "violation" if outside else "neither"] += 1
    assert min(seen.values()) >= 5, seen


def test_fifty_pushes_without_success_give_a_soft_reset(cell: TwinCell) -> None:
    cell.set_arm_state("left", (0.5, 0.5), 0.0, (0.8, 0.3), pushes_since_goal=48)
    out = cell.push({"left": 2})["left"]  # away from the goal
    assert out == TwinOutcome(False, False, False)
    assert cell.arm_state("left").pushes_since_goal == 49
    out = cell.push({"left": 2})["left"]
    assert out == TwinOutcome(success=False, violation=False, soft_reset=True)
    state = cell.arm_state("left")
    assert state.pushes_since_goal == 0 and state.goal_xy != (0.8, 0.3)
    assert math.dist(state.goal_xy, state.cube_xy) >= MIN_GOAL_DISTANCE


def test_hard_resets_and_goals_stay_within_their_bounds(cell: TwinCell) -> None:
    for _ in range(100):
        cell.hard_reset("right")
        s = cell.arm_state("right")
        assert max(abs(v - 0.5) for v in s.cube_xy) <= RESET_NOISE + 1e-3
        assert -math.pi / 4 <= s.yaw < math.pi / 4
        assert depth_inside(s.goal_xy) >= GOAL_MARGIN
        assert math.dist(s.goal_xy, s.cube_xy) >= MIN_GOAL_DISTANCE


def test_set_arm_state_round_trips(cell: TwinCell) -> None:
    cell.set_arm_state("right", (0.31, 0.62), 0.3, (0.7, 0.2))
    s = cell.arm_state("right")
    assert s.cube_xy == pytest.approx((0.31, 0.62), abs=1e-9)
    assert s.yaw == pytest.approx(reduce_yaw(0.3), abs=1e-6)
    assert s.goal_xy == (0.7, 0.2) and not s.violating
    cell.set_arm_state("right", (0.05, 0.5), 0.0, (0.7, 0.2))
    assert cell.arm_state("right").violating


def test_expert_action_is_the_supervisor_choice(cell: TwinCell) -> None:
    cell.set_arm_state("left", (0.5, 0.5), 0.0, (0.5, 0.2))
    assert cell.expert_action("left") == 0
    cell.set_arm_state("right", (0.5, 0.5), 0.0, (0.8, 0.5))
    assert cell.expert_action("right") == 3


def test_bad_calls_are_clear_errors() -> None:
    c = TwinCell(0)
    with pytest.raises(KeyError, match="unknown arm"):
        c.push({"middle": 0})
    with pytest.raises(ValueError, match="face"):
        c.push({"left": 4})
    c.rest()
    c.close()
    c.close()
    with pytest.raises(RuntimeError, match="closed"):
        c.observe()
    with pytest.raises(RuntimeError, match="closed"):
        c.push({"left": 0})


def test_push_primitive_geometry() -> None:
    """The primitive starts 8/64 of the workspace outside the face, on the face normal
    (up to the sideways offset), and ends at the cube's centre."""
    from sim_twin.constants import CUBE_M, PUSHER_RADIUS_M, WORKSPACE_M
    from sim_twin.world import TwinWorld

    normal = (math.cos(0.4), math.sin(0.4))
    s = TwinWorld.plan_stroke(0, (0.1, -0.2), normal, offset=0.003)
    side = (-normal[1], normal[0])
    rel = np.subtract(s.origin, (0.1, -0.2))
    face_gap = -(rel @ normal) - CUBE_M / 2 - PUSHER_RADIUS_M  # pusher surface to face
    assert face_gap == pytest.approx(8 / 64 * WORKSPACE_M)
    assert rel @ side == pytest.approx(0.003)
    assert np.subtract(s.end, (0.1, -0.2)) @ normal == pytest.approx(0.0)
    start_gap = -(np.subtract(s.start, (0.1, -0.2)) @ normal) - CUBE_M / 2 - PUSHER_RADIUS_M
    assert 0 < start_gap < face_gap


def test_same_seed_same_bytes_in_a_fresh_process() -> None:
    """Twin hosts run in their own processes: a fresh interpreter must agree too."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    code = ("import sys; sys.path.insert(0, 'tests/sim_twin'); "
            "from test_twin_cell import _trace; print('TRACE', _trace(11))")
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True,
                         text=True, timeout=120, check=True).stdout
    assert f"TRACE {_trace(11)}" in out.splitlines()
