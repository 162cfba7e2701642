"""Issue 35: the twin never answers a legal program with an internal error, and it
supervises the world zones along the path a joint move really takes.

Why: a twin whose inverse kinematics refuses a pose its own forward kinematics produced
answered a MoveL from the rest pose with event 40000 ("Twin execution hook failed"); a
real controller moves or answers with one of its codes. And a twin that checked the
zones on a straight line between a MoveJ's ends passed a path that dips into them on the
robot (rest -> a corner at travel height). Driven through the unchanged ABB client."""

from __future__ import annotations

import time
from collections import Counter
from typing import Any

import numpy as np
import twin_rws
from abb_motion_program_exec import abb_motion_program_exec_client as mpe
from twin_rws import our_twin, program, run, stay

from sim_twin.rws.testbed_rapid import WORLD_ZONE_CODE
from sim_twin.yumi_arms import DEFAULT_TOOL_MM, ArmModel, abb_to_chain
from sim_twin.yumi_geometry import REST_JOINTS_DEG
from sim_twin.yumi_ik import solve

CASES = 6
"""Kept small: an unreachable target costs the IK its broad search (seconds each)."""
CONTROLLER_CODES = {50050, 50027, 50026, 50080, 50204, WORLD_ZONE_CODE, 80001}
"""Every answer the twin may give besides a motion: the controller's kinematic and
supervision codes, a world zone, our RAPID's refusal (ErrWrite 80001)."""


def errors(entries: list[Any]) -> list[tuple[int, str]]:
    return [(e.code, e.title) for e in entries if e.msgtype == 3]


def test_inverse_kinematics_finds_every_pose_forward_kinematics_made() -> None:
    rng = np.random.default_rng(35)
    for side in ("left", "right"):
        m = ArmModel(side)
        rest = abb_to_chain(REST_JOINTS_DEG[side])
        for _ in range(25):
            q = rng.uniform(m.lower * 0.9, m.upper * 0.9)
            f = m.pose(q).flange
            s = solve(m, f, q[2], None, current=rest, seeds=[q])
            assert s.pose is not None, (side, q, s)
        s = solve(m, m.pose(rest).flange, rest[2], None, current=rest, seeds=[rest])
        assert s.pose is not None  # the rest pose itself (tool forward, not down)


def test_movel_straight_from_rest_is_a_motion_or_a_controller_code() -> None:
    with our_twin() as tw:
        for target in ((310, -210, 100), (200, -400, 300), (150, -300, 10)):
            got = run(tw.c, {"T_ROB_R": program([("L", target, 200)]), "T_ROB_L": stay()})
            assert {c for c, _ in errors(got)} <= CONTROLLER_CODES, got
            back = tw.tcps()["right"]
            run(tw.c, {"T_ROB_R": program([("L", (back[0], back[1], 130), 200),
                                           ("R", "right", 300)]), "T_ROB_L": stay()})


def test_a_joint_move_from_rest_to_travel_height_dips_into_the_zone_and_is_stopped() -> None:
    with our_twin() as tw:
        got = run(tw.c, {"T_ROB_L": program([("J", (150, 370, 40), 500)]), "T_ROB_R": stay()})
        assert [c for c, _ in errors(got)] == [WORLD_ZONE_CODE]  # the straight line would pass
        tip = tw.tcps()["left"]
        assert tip[2] < 100.0 and tip[0] < 150.0  # stopped on the way, near the body
    with our_twin() as tw:  # above the target by joints, then straight down: no stop
        got = run(tw.c, {"T_ROB_L": program([("J", (150, 370, 120), 500),
                                             ("L", (150, 370, 40), 200)]), "T_ROB_R": stay()})
        assert errors(got) == []
        assert np.allclose(tw.tcps()["left"], (150, 370, 40), atol=1.0)


def _random_program(rng: np.random.Generator, side: str, tool_mm: float) -> Any:
    sign = 1.0 if side == "left" else -1.0
    mp = mpe.MotionProgram(tool=twin_rws.tool(tool_mm))
    for _ in range(int(rng.integers(1, 4))):
        kind = rng.choice(["J", "L", "A", "W"], p=[0.35, 0.35, 0.2, 0.1])
        speed = mpe.speeddata(float(rng.uniform(50, 800)), 500, 5000, 1000)
        if kind == "W":
            mp.WaitTime(float(rng.uniform(0, 0.05)))
        elif kind == "A":
            j = np.asarray(REST_JOINTS_DEG[side]) + rng.normal(0, 25, 7)
            mp.MoveAbsJ(mpe.jointtarget(list(j[:6]), [float(j[6])] + [9e9] * 5), speed, mpe.fine)
        else:
            xyz = [float(rng.uniform(0, 750)), sign * float(rng.uniform(-100, 750)),
                   float(rng.uniform(0, 500))]
            q = rng.normal(size=4) if rng.random() < 0.3 else np.array(twin_rws.DOWN)
            q = q / np.linalg.norm(q)
            angle = sign * float(rng.uniform(60, 168))
            target = mpe.robtarget(xyz, list(q), mpe.confdata(0, 0, 0, 4), [angle] + [9e9] * 5)
            (mp.MoveJ if kind == "J" else mp.MoveL)(target, speed, mpe.fine)
    return mp


def test_random_programs_end_in_a_motion_or_a_controller_code() -> None:
    """Seeded random programs (targets across and beyond the reach, random orientations
    and arm angles, one or two arms, MoveAbsJ/MoveJ/MoveL/WaitTime), each started from
    wherever the previous left the arms (rest, a stop, mid-table): never 40000."""
    rng = np.random.default_rng(20235)
    outcomes: Counter[int] = Counter()
    t0 = time.monotonic()
    with our_twin() as tw:
        for k in range(CASES):
            arms = [("T_ROB_L", "left"), ("T_ROB_R", "right")]
            if rng.random() < 0.5:
                arms = [arms[int(rng.integers(2))]]
            progs = {task: _random_program(rng, side, DEFAULT_TOOL_MM) for task, side in arms}
            for task in ("T_ROB_L", "T_ROB_R"):
                progs.setdefault(task, stay())
            t1 = time.monotonic()
            got = run(tw.c, progs, seqno=k + 1)
            print(k, f"{time.monotonic() - t1:.1f} s", [c for c, _ in errors(got)])
            codes = [c for c, _ in errors(got)]
            assert set(codes) <= CONTROLLER_CODES, (k, got)
            outcomes.update(codes or [0])
            if k % 10 == 9:  # back to rest now and then, as the driver does
                for side in ("left", "right"):
                    p = tw.tcps()[side]
                    run(tw.c, {f"T_ROB_{side[0].upper()}": program(
                        [("L", (p[0], p[1], max(p[2], 130.0)), 200), ("R", side, 300)])})
    print(f"outcomes {dict(outcomes)} in {time.monotonic() - t0:.1f} s")
    assert outcomes[0] > 0  # some programs move
