"""Issue 35 on the operator's side: the paths to and from rest stay out of the world zones,
the tool frame is never a silent flange, the zones are known active since the last
restart, and ``testbed check`` words what the YuMi's operator really does.

The arm's model (``drivers/yumi/irb14000.py``) plays the driver's own programs
(``drivers/yumi/path_sweep.py``) from the shipped rest pose (ABB's folded arm and wrist,
axis 1 swung back 40 deg, axis 2 at -90: ``sim_twin/yumi_geometry.py``) with the
184.2 mm pusher,
against the shipped zones (robot/rapid/TestbedTask_L.mod: box x 125..495, y 25..395 for
the left arm, below z 80; the floor at 0).
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from drivers.errors import BackendError
from drivers.yumi.arm_calibration import ArmCalibration
from drivers.yumi.backend import ArmSetup, plan_push, refuse_unreachable
from drivers.yumi.controller_state import (
    RAPID_VERSION,
    ControllerState,
    option_warnings,
    problems,
    refusal,
    tool_problem,
)
from drivers.yumi.gate import calibration_gate_joints, model_gate_joints
from drivers.yumi.irb14000 import arm
from drivers.yumi.layout_check import JOINT_MARGIN_MM, PATH_MARGIN_MM, check_layout, layout_of
from drivers.yumi.path_sweep import ZoneSpec, play, worst
from drivers.yumi.reach import ARM_ANGLE_DEG, ArmTool
from drivers.yumi.yumi_controller import Waypoint
from drivers.yumi.zones_proof import zones_known, zones_refusal

PUSHER = 184.2
REST = {"left": (40.0, -90.0, 30.0, 0.0, 40.0, 0.0, 135.0),
        "right": (-40.0, -90.0, 30.0, 0.0, 40.0, 0.0, -135.0)}
BOX = {"left": (150.0, 50.0, 470.0, 370.0), "right": (150.0, -370.0, 470.0, -50.0)}
ZONES = {"left": ZoneSpec((125.0, 25.0, 495.0, 395.0), 80.0, 0.0),
         "right": ZoneSpec((125.0, -395.0, 495.0, -25.0), 80.0, 0.0)}


def calibration(side: str, **over: Any) -> dict[str, Any]:
    """A calibration of the shipped layout (an identity-like homography: the paths do
    not depend on it), with the 184.2 mm pusher and the gate joints ``testbed
    calibrate`` writes for its gate (the model's: drivers/yumi/gate.py)."""
    cal = {"homography": [[0, 1, 0], [1, 0, 0], [0, 0, 1]], "table_box_mm": list(BOX[side]),
           "z_push_mm": 10.0, "z_travel_mm": 80.0, "tool_z_mm": PUSHER,
           "arm_angle_deg": ARM_ANGLE_DEG[side],
           "rest_joints_deg": list(REST[side]),
           "task": "T_ROB_L" if side == "left" else "T_ROB_R", **over}
    return {"gate_joints_deg": calibration_gate_joints(side, cal), **cal}


def tool(side: str) -> ArmTool:
    return ArmTool(side, PUSHER, ARM_ANGLE_DEG[side])


def rest_chain(side: str) -> tuple[float, ...]:
    return arm(side).pose_abb(REST[side]).chain_deg


@pytest.mark.parametrize("side", ["left", "right"])
def test_the_old_path_from_rest_dips_into_the_zone(side: str) -> None:
    """The driver's first move before issue 35: rest by joints straight to travel height
    over the table. Over the box's far inner corner the tip swings under tb_zone_z
    outside the box (the model, the target's joints at the held arm angle: (122, +-270,
    75)); raising travel height does not cure it."""
    s = 1.0 if side == "left" else -1.0
    for z in (80.0, 100.0):
        samples, err = play(tool(side), rest_chain(side), REST[side],
                            [Waypoint("move_j", (470.0, 50.0 * s, z), 100.0)])
        assert err is None
        w = worst(samples, tool(side), ZONES[side])
        assert w is not None and w.clearance < 0, w
        assert w.point[2] < 80 and not (25 <= s * w.point[1] <= 395 and 125 <= w.point[0] <= 495)


def test_the_old_gate_skims_the_zone_and_the_new_one_keeps_clear() -> None:
    """The gate H2 chose for ABB's exact home (a quarter into the box from its near and
    inner edges, (230, 130, 100)) skims tb_zone_z outside the box from the shipped rest
    (the tip 1 mm over it at about (123, 200, 81)): a zone stop on a robot a few mm off
    the model. The default gate now (half way in, five eighths out: (310, 250)) keeps
    about 40 mm clear, the tip never under z 120 outside the zone box, on the way there
    and back (MoveAbsJ to rest)."""
    from drivers.yumi.paths import gate_xy

    for side in ("left", "right"):
        s = 1.0 if side == "left" else -1.0
        assert gate_xy(BOX[side]) == (310.0, 250.0 * s)
        legs = {}
        for g in ((230.0, 130.0 * s), gate_xy(BOX[side])):
            joints = model_gate_joints(tool(side), (*g, 100.0), REST[side])
            assert not isinstance(joints, str)
            there, err = play(tool(side), rest_chain(side), REST[side],
                              [Waypoint("abs_j", None, 100.0, joints_deg=joints)])
            back, err2 = play(tool(side), there[-1].pose.chain_deg, REST[side],
                              [Waypoint("rest", None, 100.0)])
            assert err is None and err2 is None
            legs[g] = [*there, *back]
        old, new = legs.values()
        w_old = worst(old, tool(side), ZONES[side])
        w = worst(new, tool(side), ZONES[side])
        assert w_old is not None and w_old.clearance < 10, w_old
        assert w is not None and w.clearance >= 35, w
        x0, y0, x1, y1 = ZONES[side].box or (0, 0, 0, 0)
        outside = [p.tip[2] for p in new
                   if not (x0 <= p.tip[0] <= x1 and y0 <= p.tip[1] <= y1)]
        assert outside and min(outside) > 80 + 40, min(outside)


@pytest.mark.slow  # 40 pushes planned: up to 20 s
@pytest.mark.parametrize("side", ["left", "right"])
def test_the_drivers_push_paths_stay_clear_of_the_zones(side: str) -> None:
    """Every push the driver plans (cubes over the workspace, every face), played from
    rest through the model: the tip and the links stay PATH_MARGIN_MM clear of the
    zones. Fails on the old planning (a joint move from rest to travel height)."""
    setup = ArmSetup(side, (0, 0, 320, 320), False,
                     ArmCalibration.from_dict(calibration(side), side))
    least = 1e9
    for centre in ((0.2, 0.2), (0.8, 0.2), (0.8, 0.8), (0.2, 0.8), (0.5, 0.5)):
        for face in range(4):
            wps = plan_push(setup, centre, 0.0, face)
            samples, err = play(tool(side), rest_chain(side), REST[side], wps)
            if err is not None:  # at the edge of reach (the inner near corner at clear
                with pytest.raises(BackendError, match="nothing was moved"):  # height):
                    refuse_unreachable(side, setup.calibration, wps)  # refused first
                continue
            w = worst(samples, tool(side), ZONES[side])
            assert w is not None
            least = min(least, w.clearance)
            assert w.clearance >= PATH_MARGIN_MM, (centre, face, w)
    assert least < 40  # the figure: the table box's 25 mm inside the zone box


SHIPPED_ZONES = {"tb_zone_lo": [125, 25, 0], "tb_zone_hi": [495, 395, 0], "tb_zone_z": 80,
                 "tb_floor_z": 0}


def test_the_layout_check_faults_a_path_that_dips_and_passes_the_shipped_one() -> None:
    """Every part of the driver's paths is swept and FAULTed on its own: the joint move
    from rest to the gate joints, the correction at the gate, the joint move back to
    rest (the way back, issue 43) and the straight legs. A gate whose ways out and back
    dip (the old gate at (230, 130)) is a FAULT naming each. On the shipped box (y 75 to
    370) every path is clear, its inner near corner too (issue 43: with axis 7 held no
    straight line from the gate reached it; every target is now solved at the arm angle
    its robtarget carries, drivers/yumi/reach.py)."""
    good = layout_of("left", calibration("left", table_box_mm=[150, 75, 470, 370]),
                     zones=SHIPPED_ZONES)
    assert good is not None
    lines, faults = check_layout([good])
    assert faults == []
    line = next(x for x in lines if "paths (rest by joints to the gate (310, 259, 100)" in x)
    got = {part: int(n) for part, n in re.findall(r"on (the [a-z ]+) (-?\d+) mm", line)}
    assert set(got) == {"the joint moves from rest", "the correction at the gate",
                        "the joint moves back to rest", "the straight moves"}, line
    assert got["the joint moves from rest"] >= JOINT_MARGIN_MM + 15, line
    assert got["the joint moves back to rest"] >= JOINT_MARGIN_MM + 15, line
    assert got["the correction at the gate"] >= JOINT_MARGIN_MM, line
    assert got["the straight moves"] >= PATH_MARGIN_MM, line
    bad = layout_of("left", calibration("left", gate_xy_mm=[230, 130]), zones=SHIPPED_ZONES)
    assert bad is not None
    _, faults = check_layout([bad])
    for leg in ("joint move to the gate joints", "joint move to rest"):  # out, and back
        assert any(re.match(rf"arm left: on the driver's path .*{leg}, its .* comes to "
                            rf"\(\d+, \d+, \d+\) mm, \d+ mm (from|inside) a world zone "
                            rf".*want 20 mm clear", f) for f in faults), (leg, faults)


def test_the_correction_is_swept_from_every_solution_of_the_gates_pose() -> None:
    """A line back to the gate's point may arrive in any of its pose's solutions (the
    twin's pushes come back in the gate's own, or with axis 4 turned by about 170 deg, or
    by a whole turn): the sweep plays the correction from each of them."""
    from drivers.yumi.gate import gate_solutions
    from drivers.yumi.layout_check import corrections

    lay = layout_of("right", calibration("right"), zones={
        "tb_zone_lo": [125, -395, 0], "tb_zone_hi": [495, -25, 0], "tb_zone_z": 80})
    assert lay is not None and lay.gate_joints_deg is not None
    gate = arm("right").pose_abb(lay.gate_joints_deg).chain_deg
    sols = [arm("right").pose(q).abb_deg for q in gate_solutions(lay.tool, lay.gate_xyz, gate)]
    assert len(sols) >= 3
    axis4 = sorted(round(q[3]) for q in sols)
    assert any(abs(a - lay.gate_joints_deg[3]) < 1 for a in axis4)  # the gate's own
    assert any(abs(a - lay.gate_joints_deg[3]) > 150 for a in axis4)  # the wrist over
    legs = {smp.leg for smp in corrections(lay, gate)}
    assert len(legs) == len(sols) and all("the correction at the gate" in g for g in legs)
    for q in sols:  # every one puts the tip at the gate, the pusher down
        tip = arm("right").pose_abb(q).tcp(PUSHER)
        assert tip == pytest.approx(lay.gate_xyz, abs=0.5)


def test_a_calibration_without_or_with_wrong_gate_joints_is_a_fault() -> None:
    cal = calibration("left")
    del cal["gate_joints_deg"]
    lay = layout_of("left", cal, zones=SHIPPED_ZONES)
    assert lay is not None
    lines, faults = check_layout([lay])
    assert [f for f in faults if f.startswith("arm left: its calibration has no "
                                              "'gate_joints_deg'")
            and "run testbed calibrate" in f], faults
    assert not [x for x in lines if "paths (" in x]  # nothing to sweep without them
    off = calibration("left")
    off["gate_joints_deg"] = [off["gate_joints_deg"][0] + 15.0, *off["gate_joints_deg"][1:]]
    lay = layout_of("left", off, zones=SHIPPED_ZONES)
    assert lay is not None
    _, faults = check_layout([lay])
    assert [f for f in faults if re.match(r"arm left: gate_joints_deg \[.*\] put the pusher's "
                                          r"tip at \(.*\) mm \(the model\), \d+ mm from the "
                                          r"gate \(310, 250, 100\)", f)], faults
    # the pusher at the gate, the elbow at another arm angle than the calibration's
    turned = calibration_gate_joints("left", {**calibration("left"), "arm_angle_deg": -20.0})
    lay = layout_of("left", calibration("left", gate_joints_deg=turned), zones=SHIPPED_ZONES)
    assert lay is not None
    _, faults = check_layout([lay])
    assert [f for f in faults if re.match(r"arm left: gate_joints_deg \[.*\] hold the elbow at "
                                          r"arm angle -20\.0 deg .* not the calibration's "
                                          r"arm_angle_deg -40", f)], faults


def test_an_old_axis_7_arm_angle_is_refused_with_the_fix_and_the_default_is_the_held_one(
        ) -> None:
    """Issue 43: a calibration's ``arm_angle_deg`` is ABB's arm angle every target is
    solved at; an older file holds axis 7's value there (+-130), which a controller would
    read as an arm angle no push can take: refused, naming the field and the fix. Absent:
    the driver's -40 (left) / +40 (right)."""
    with pytest.raises(BackendError, match=r"'arm_angle_deg' is 130: ABB's arm angle, at "
                                           r"most 90 deg either way; an older calibration held "
                                           r"axis 7's value there \(\+-130\): set it to -40 or "
                                           r"remove it"):
        ArmCalibration.from_dict(calibration("left", arm_angle_deg=130.0), "left")
    with pytest.raises(BackendError, match=r"'arm_angle_deg' must be a number"):
        ArmCalibration.from_dict(calibration("left", arm_angle_deg="up"), "left")
    for side, want in (("left", -40.0), ("right", 40.0)):
        cal = calibration(side)
        del cal["arm_angle_deg"]
        pose = ArmCalibration.from_dict(cal, side).pose
        assert pose is not None and pose.arm_angle_deg == want
    assert ArmCalibration.from_dict(calibration("left", arm_angle_deg=-90.0),
                                    "left").pose.arm_angle_deg == -90.0  # type: ignore[union-attr]


def test_a_calibration_without_tool_z_mm_is_an_error(tmp_path: Path) -> None:
    f = tmp_path / "left.json"
    d = calibration("left")
    del d["tool_z_mm"]
    f.write_text(json.dumps(d))
    with pytest.raises(BackendError, match=rf"arm left: {re.escape(str(f))}: has no "
                                           r"'tool_z_mm' .*4-point TCP.*robot/README.md, "
                                           r"'The tool frame'"):
        ArmCalibration.load(f, "left")
    with pytest.raises(BackendError, match=r"z_clear_mm .* must be at or above z_travel_mm"):
        ArmCalibration.from_dict(calibration("left", z_clear_mm=60.0), "left")


def test_the_controllers_tool_frame_is_compared() -> None:
    same = {"trans": [0.0, 0.0, 184.2], "rot": [1.0, 0.0, 0.0, 0.0], "mass": 0.272}
    assert tool_problem("T_ROB_L", same, 184.6) is None
    off = tool_problem("T_ROB_L", same, 100.0)
    assert off is not None and "tool_z_mm 100 is not the controller's tool_pusher" in off
    turned = {**same, "rot": [0.9999, 0.0141, 0.0, 0.0]}  # about 1.6 deg
    assert tool_problem("T_ROB_L", turned, 184.2) is not None


def entry(seq: int, code: int, title: str = "", args: tuple[str, ...] = ()) -> Any:
    return SimpleNamespace(seqnum=seq, code=code, msgtype=1, title=title, args=list(args),
                           desc="", causes="")


def active(seq: int, task: str, n: int = 5) -> Any:
    return entry(seq, 80003, "Testbed Zones Active",
                 ("Testbed Zones Active", task, f"zones {n}", "2026-01-01"))


def test_zones_must_be_known_active_since_the_last_restart() -> None:
    """Fails closed (issue 43): a restart entry AND, newer than it, each task's Zones
    Active entry; a log with neither left (cleared, rolled over) proves nothing."""
    fresh = [active(12, "T_ROB_R"), active(11, "T_ROB_L"), entry(10, 10045, "System restarted")]
    stale = [entry(20, 10045, "System restarted"), *fresh]
    assert zones_known(fresh, "T_ROB_L")["known"] and not zones_known(stale, "T_ROB_L")["known"]
    assert zones_refusal(fresh, ["T_ROB_L", "T_ROB_R"]) is None
    why = zones_refusal(stale, ["T_ROB_L", "T_ROB_R"])
    assert why is not None and why.startswith("task T_ROB_L: the world zones are not known "
                                              "active: no 'Testbed Zones Active' entry")
    assert "since the last restart (event log 10045, seq 20)" in why
    for gone in ([], fresh[:2]):  # cleared, or rolled past the restart entry: not known
        why = zones_refusal(gone, ["T_ROB_L"])
        assert why is not None and "holds no restart entry (cleared over RWS, or rolled " \
                                   "over)" in why and "restart the controller so tb_zones " \
                                   "runs" in why, why
    cold = [active(31, "T_ROB_L"), entry(30, 10046, "System restarted in cold mode")]
    assert zones_known(cold, "T_ROB_L")["known"]  # 10046 is a restart too
    assert not zones_known([entry(40, 10046), *cold], "T_ROB_L")["known"]
    short = [active(12, "T_ROB_L", n=3), entry(10, 10045, "System restarted")]
    assert "says zones 3, not 5" in str(zones_refusal(short, ["T_ROB_L"]))
    rep = {"options": ["608-1", "616-1", "604-1"],
           "state": {"opmode": "AUTO", "ctrlstate": "motoron", "execstate": "stopped"},
           "tasks": {"T_ROB_L": {}},
           "rapid": {"T_ROB_L": {"version": RAPID_VERSION, "zones": {},
                                 "zones_known": zones_known(stale, "T_ROB_L")}}}
    faults = problems(rep, ["T_ROB_L"])
    assert any("since the last restart (event log 10045, seq 20)" in f
               and "POWER_ON event routine" in f for f in faults), faults
    rep["rapid"]["T_ROB_L"]["zones_known"] = zones_known(fresh, "T_ROB_L")
    assert problems(rep, ["T_ROB_L"]) == []
    rep["rapid"]["T_ROB_L"]["zones_known"] = zones_known([], "T_ROB_L")  # a cleared log
    assert [f for f in problems(rep, ["T_ROB_L"]) if "holds no restart entry" in f]


def test_the_operator_is_told_what_a_yumi_has() -> None:
    manual = refusal(ControllerState("MANR", "motoron", "stopped"))
    off = refusal(ControllerState("AUTO", "motoroff", "stopped"))
    assert manual is not None and "turn the key switch" not in manual
    assert "FlexPendant" in manual
    assert off is not None and "Motors On button on the controller" not in off
    assert "FlexPendant" in off
    rep = {"options": ["608-1", "616-1", "604-2"]}
    assert not [p for p in problems({**rep, "state": {"opmode": "AUTO",
                                                      "ctrlstate": "motoron",
                                                      "execstate": "stopped"}}, [])
                if "623-1" in p]
    assert [w for w in option_warnings(rep) if "623-1 Multitasking" in w]


def test_a_layout_checked_again_is_answered_as_before_and_a_changed_one_anew() -> None:
    """``check_layout`` keeps its answers (a process asks it at every run's start); the
    same arms get equal answers, which a caller may change without touching the kept
    ones, and a calibration that differs in its last digit is checked anew."""
    from drivers.yumi import layout_check

    good = layout_of("left", calibration("left", table_box_mm=[150, 75, 470, 370]),
                     zones=SHIPPED_ZONES)
    bad = layout_of("left", calibration("left", gate_xy_mm=[230, 130]), zones=SHIPPED_ZONES)
    assert good is not None and bad is not None
    first = check_layout([good])
    first[0].append("changed by the caller")
    assert check_layout([good]) == (first[0][:-1], first[1])
    assert len(layout_check._KEPT) == 1
    assert check_layout([bad])[1] != []  # another layout: not the kept answer
    h = np.asarray(good.homography, dtype=np.float64) if good.homography is not None \
        else np.eye(3)
    nudged = dataclasses.replace(good, homography=h + 1e-12)
    check_layout([nudged])
    assert len(layout_check._KEPT) == 3
