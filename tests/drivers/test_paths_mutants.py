"""The YuMi's paths, waypoint for waypoint (docs/notes/tests.md, mutation testing).

Why: drivers/yumi/paths.py builds every path the controller runs between the rest pose,
the gate and the table; test_yumi_paths_zones.py sweeps them against the zones, which
a changed speed, a dropped ``fine`` or a lift at the wrong height does not show. Here
each builder's output is written out by hand from its docstring. Pure: no twin, no sshd.
"""

from __future__ import annotations

import pytest

from drivers.yumi.paths import (
    DEFAULT_Z_CLEAR_MM,
    back_to_gate,
    gate_xy,
    leave_rest,
    to_rest,
)
from drivers.yumi.yumi_controller import Waypoint

GATE_J = (10.0, -20.0, 30.0, -40.0, 50.0, -60.0, 70.0)


def test_the_default_gate_is_half_way_in_and_five_eighths_out_from_the_inner_edge() -> None:
    assert DEFAULT_Z_CLEAR_MM == 100.0
    # left arm: box y 75..370, inner edge y0 = 75
    assert gate_xy((250, 75, 470, 370)) == (360.0, 75 + 0.625 * 295)
    # right arm: box y -370..-75, inner edge y1 = -75
    assert gate_xy((250, -370, 470, -75)) == (360.0, -75 - 0.625 * 295)
    # equal distances: y0 counts as the inner edge
    assert gate_xy((0, -100, 100, 100)) == (50.0, -100 + 0.625 * 200)
    # a calibration's gate wins, as floats
    got = gate_xy((250, 75, 470, 370), (300, 200))
    assert got == (300.0, 200.0) and all(type(v) is float for v in got)


def test_leave_rest_is_a_joint_move_to_the_gate_then_straight_over_the_target() -> None:
    assert leave_rest([int(v) for v in GATE_J], (400, 250), 130.0, 80.0) == [
        Waypoint("abs_j", None, 80.0, fine=True, joints_deg=GATE_J),
        Waypoint("move_l", (400.0, 250.0, 130.0), 80.0, fine=True),
    ]


def test_to_rest_goes_straight_to_the_gate_point_then_by_joints() -> None:
    assert to_rest((310.0, 259.0), GATE_J, 100.0, 60.0) == [
        Waypoint("move_l", (310.0, 259.0, 100.0), 60.0, fine=True),
        Waypoint("abs_j", None, 60.0, fine=True, joints_deg=GATE_J),
        Waypoint("rest", None, 60.0, fine=True),
    ]


def test_back_to_gate_lifts_first_only_when_below_travel_height() -> None:
    tail = [Waypoint("move_l", (310.0, 259.0, 100.0), 60.0),
            Waypoint("abs_j", None, 60.0, joints_deg=GATE_J)]
    low = back_to_gate((400, 250, 20), (310.0, 259.0), GATE_J, 130.0, 100.0, 60.0, 15.0, 2.0)
    assert low == [Waypoint("move_l", (400.0, 250.0, 130.0), 15.0), *tail]
    # z = travel height - tolerance (128): not below it, so no lift
    at = back_to_gate((400, 250, 128), (310.0, 259.0), GATE_J, 130.0, 100.0, 60.0, 15.0, 2.0)
    assert at == tail
    just_below = back_to_gate((400, 250, 127.9), (310.0, 259.0), GATE_J, 130.0, 100.0, 60.0,
                              15.0, 2.0)
    assert just_below[0] == Waypoint("move_l", (400.0, 250.0, 130.0), 15.0)
    assert just_below[1:] == tail


@pytest.mark.parametrize("joints", [GATE_J[:6], (*GATE_J, 0.0)])
def test_a_joint_target_needs_seven_angles(joints: tuple[float, ...]) -> None:
    with pytest.raises(ValueError, match=rf"^a joint target needs 7 angles \(axes 1-6, then "
                                         rf"7\), got {len(joints)}$"):
        leave_rest(joints, (400, 250), 130.0, 80.0)
