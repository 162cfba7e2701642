"""Perception against the twin's ground truth, and its pieces on drawn images."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sim_twin
from sim_twin import TwinCell
from sim_twin.constants import GOAL_RADIUS as TWIN_GOAL_RADIUS
from sim_twin.constants import GOAL_RGB as TWIN_GOAL_RGB
from sim_twin.constants import TABLE_RGB
from sim_twin.overhead_camera import draw_goal as twin_draw_goal
from testbed.core.types import SUCCESS_RADIUS
from testbed.perception import cube as P


def test_workspace_polygon_is_the_twins() -> None:
    np.testing.assert_array_equal(P.WORKSPACE_POLYGON, sim_twin.WORKSPACE_POLYGON)
    assert P.GOAL_RADIUS == TWIN_GOAL_RADIUS and P.GOAL_RGB == TWIN_GOAL_RGB


def test_workspace_depth_and_violation() -> None:
    assert P.workspace_depth((0.5, 0.5)) == pytest.approx(0.425)
    assert P.workspace_depth((0.08, 0.5)) == pytest.approx(0.005)
    assert P.workspace_depth((0.07, 0.5)) < 0
    assert P.workspace_depth((0.15, 0.15)) < 0  # the cut top-left corner
    assert P.workspace_depth((0.85, 0.15)) > 0  # the top-right corner is not cut
    assert P.workspace_depth((0.85, 0.85)) < 0  # the cut bottom-right corner
    pose = P.CubePose((0.5, 0.5), 0.0, 64.0)
    assert not P.is_violation(pose)
    assert P.is_violation(P.CubePose((0.5, 0.95), 0.0, 64.0))
    assert P.is_violation(None)  # no cube in view: it left the workspace


def test_success_decision() -> None:
    pose = P.CubePose((0.5, 0.5), 0.0, 64.0)
    assert P.is_success(pose, (0.5 + SUCCESS_RADIUS * 0.99, 0.5))
    assert not P.is_success(pose, (0.5 + SUCCESS_RADIUS * 1.01, 0.5))
    assert not P.is_success(None, (0.5, 0.5))
    assert not P.is_success(pose, None)


def test_empty_table_and_bad_input() -> None:
    table = np.empty((64, 64, 3), np.uint8)
    table[:] = TABLE_RGB
    assert P.find_cube(table) is None
    assert P.find_goal(table) is None
    with pytest.raises(ValueError, match="uint8"):
        P.find_cube(np.zeros((64, 64), np.uint8))


def test_goal_disc_drawn_and_found() -> None:
    rng = np.random.default_rng(0)
    for _ in range(200):
        goal = tuple(rng.uniform(0.1, 0.9, 2))
        a = np.empty((64, 64, 3), np.uint8)
        a[:] = TABLE_RGB
        b = a.copy()
        P.draw_goal(a, goal)
        twin_draw_goal(b, goal)
        np.testing.assert_array_equal(a, b)  # hosts and twin paint the same disc
        found = P.find_goal(a)
        assert found is not None and math.dist(found, goal) * 64 < 0.35


def _random_states(cell: TwinCell, rng: np.random.Generator) -> None:
    """Half anywhere in the crop (edges, violations), half near the goal (decisions)."""
    for arm in cell.arm_names:
        goal = rng.uniform(0.2, 0.8, 2)
        if rng.random() < 0.5:
            xy = rng.uniform(0.0, 1.0, 2)
        else:
            a, r = rng.uniform(0, 2 * math.pi), rng.uniform(0, 2 * SUCCESS_RADIUS)
            xy = goal + r * np.array([math.cos(a), math.sin(a)])
        cell.set_arm_state(arm, xy, rng.uniform(-math.pi / 4, math.pi / 4), goal)


def test_perception_agrees_with_the_twins_ground_truth() -> None:
    """>= 1000 random states: median centre error <= 1 px, decisions agree >= 99%."""
    rng = np.random.default_rng(0)
    centre_err, yaw_err, goal_err = [], [], []
    n = success_agree = violation_agree = successes = violations = 0
    with TwinCell(5) as cell:
        for _ in range(520):
            _random_states(cell, rng)
            images = cell.observe()
            for arm in cell.arm_names:
                truth, image = cell.arm_state(arm), images[arm]
                pose, goal = P.find_cube(image), P.find_goal(image)
                true_success = (not truth.violating
                                and math.dist(truth.cube_xy, truth.goal_xy) <= SUCCESS_RADIUS)
                # The fleet loop decides success with the goal it drew (find_goal cannot
                # see a goal the cube sits on).
                success_agree += P.is_success(pose, truth.goal_xy) == true_success
                violation_agree += P.is_violation(pose) == truth.violating
                successes += true_success
                violations += truth.violating
                n += 1
                if pose is not None and 0.07 < min(truth.cube_xy) <= max(truth.cube_xy) < 0.93:
                    centre_err.append(math.dist(pose.centre, truth.cube_xy) * 64)
                    d = pose.yaw - truth.yaw
                    yaw_err.append(abs((d + math.pi / 4) % (math.pi / 2) - math.pi / 4))
                if goal is not None and math.dist(truth.cube_xy, truth.goal_xy) > 0.16:
                    goal_err.append(math.dist(goal, truth.goal_xy) * 64)
    assert n >= 1000 and successes >= 200 and violations >= 100
    assert np.median(centre_err) <= 1.0
    assert np.percentile(centre_err, 99) <= 1.0
    assert success_agree / n >= 0.99
    assert violation_agree / n >= 0.99
    assert math.degrees(float(np.median(yaw_err))) <= 5.0
    assert np.median(goal_err) <= 0.5
