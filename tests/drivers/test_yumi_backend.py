"""The YuMi backend at its boundaries: FakeYumiController and a video-file camera.

The video frames are overhead pictures of a twin cell at 4x (576 x 256), so the
perception that judges them is the project's own; the calibration maps camera pixels
to the robot base frame with a known homography, so every waypoint can be checked.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from driver_fakes import (
    YUMI_BOXES,
    YUMI_CROPS,
    YUMI_IN_VIEW,
    YUMI_REST,
    local_host,
    make_yumi,
    twin_picture,
    write_video,
    yumi_calibration,
    yumi_joints,
)

from drivers.backends.base import ArmOutcome
from drivers.errors import BackendError
from drivers.host_fleet import HostFleet
from drivers.testing.fake_yumi import FakeYumiController
from drivers.yumi.arm_calibration import ArmCalibration
from drivers.yumi.arm_place import JOINT_TOLERANCE_DEG
from drivers.yumi.backend import ArmSetup, YumiBackend, plan_push
from drivers.yumi.controller_state import RAPID_VERSION
from drivers.yumi.credentials import FACTORY_DEFAULT, FACTORY_LOGIN
from drivers.yumi.rws_controller import RwsYumiController
from drivers.yumi.yumi_controller import ArmPose, Waypoint
from drivers.yumi.zones_proof import ZONES_ACTIVE
from testbed.core.host_config import ArmConfig
from testbed.core.types import MIN_GOAL_DISTANCE, ArmObservation, Fault


def setup(arm: str) -> ArmSetup:
    return ArmSetup(arm, YUMI_CROPS[arm], arm == "right",
                    ArmCalibration.from_dict(yumi_calibration(arm), arm))


def inside_box(arm: str, w: Waypoint) -> bool:
    x0, y0, x1, y1 = YUMI_BOXES[arm]
    assert w.xyz_mm is not None
    return x0 <= w.xyz_mm[0] <= x1 and y0 <= w.xyz_mm[1] <= y1


@pytest.mark.parametrize(("arm", "face", "axis", "sign"), [
    ("left", 3, 1, +1),   # canonical right -> camera u grows -> robot y grows
    ("left", 2, 0, +1),   # canonical down -> camera v grows -> robot x grows
    ("right", 3, 1, -1),  # the right arm's crop is mirrored: canonical right is -u
    ("right", 0, 0, -1),
])
def test_push_maps_through_the_calibration(arm: str, face: int, axis: int, sign: int) -> None:
    wps = plan_push(setup(arm), (0.5, 0.5), 0.0, face)
    # by joints (MoveAbsJ) from rest to the gate joints, straight (a slant) to above the
    # start at travel height, down to push height, the stroke, up, straight to the
    # gate's point at clear height, by joints to the gate joints (the correction), by
    # joints to rest
    assert [w.kind for w in wps] == ["abs_j", "move_l", "move_l", "move_l", "move_l",
                                     "move_l", "abs_j", "rest"]
    gate = setup(arm).calibration.gate_joints_deg
    assert gate is not None and wps[0].joints_deg == wps[6].joints_deg == gate
    start, end = wps[2].xyz_mm, wps[3].xyz_mm
    assert start is not None and end is not None
    assert sign * (end[axis] - start[axis]) == pytest.approx(0.15 * 256 * 1.25)
    assert end[1 - axis] == pytest.approx(start[1 - axis])
    assert [w.xyz_mm[2] for w in wps[1:6]] == [  # type: ignore[index]
        90.0, 12.0, 12.0, 90.0, 100.0]
    assert wps[1].xyz_mm[:2] == start[:2] and wps[4].xyz_mm[:2] == end[:2]  # type: ignore[index]
    assert wps[5].xyz_mm[:2] == pytest.approx(setup(arm).calibration.gate_xy)  # type: ignore[index]
    assert wps[3].speed_mm_s == 40.0 and all(w.speed_mm_s <= 120.0 for w in wps)


def test_push_follows_the_cube_yaw() -> None:
    wps = plan_push(setup("left"), (0.5, 0.5), math.radians(30), 3)
    (x0, y0, _), (x1, y1, _) = wps[2].xyz_mm, wps[3].xyz_mm  # type: ignore[misc]
    assert math.degrees(math.atan2(x1 - x0, y1 - y0)) == pytest.approx(30, abs=1e-6)


def test_waypoints_are_clipped_into_the_table_box() -> None:
    for face in range(4):
        for centre in [(0.01, 0.01), (0.99, 0.5), (0.5, 0.99), (0.0, 1.0)]:
            for arm in ("left", "right"):
                assert all(inside_box(arm, w) for w in plan_push(setup(arm), centre, 0.3,
                                                                  face) if w.xyz_mm)


def test_calibration_errors_name_the_arm_and_the_file(tmp_path: Path) -> None:
    path = tmp_path / "cal.json"
    for bad, match in [
        ({}, "needs 'homography'"),
        ({**yumi_calibration("left"), "homography": [[1, 0, 0], [2, 0, 0], [0, 0, 1]]},
         "invertible"),
        ({**yumi_calibration("left"), "table_box_mm": [5, 0, 1, 9]}, "x_min, y_min"),
        ({**yumi_calibration("left"), "push_speed_mm_s": 500}, "push_speed_mm_s"),
        ({**yumi_calibration("left"), "z_push": 3}, "unknown key"),
        ({**yumi_calibration("left"), "rest_joints_deg": [0, 0]}, "7 angles"),
    ]:
        path.write_text(json.dumps(bad))
        with pytest.raises(BackendError, match=f"arm left: {path}: .*{match}"):
            ArmCalibration.load(path, "left")
    with pytest.raises(BackendError, match="cannot read calibration"):
        ArmCalibration.load(tmp_path / "missing.json", "left")


def test_both_arms_move_in_one_program_and_end_at_rest(tmp_path: Path) -> None:
    backend, ctrl = make_yumi(tmp_path, [twin_picture(3)])
    backend.observe()
    out = backend.push({"left": 0, "right": 2})
    assert set(out) == {"left", "right"}
    programs = ctrl.programs[-1]
    assert set(programs) == {"left", "right"}  # one MultiMove call for both arms
    for arm, wps in programs.items():
        # (an arm not yet known at rest goes there first: a rest inside the program)
        assert wps[-1].kind == "rest" and all(w.xyz_mm is None or inside_box(arm, w)
                                              for w in wps[:-1])
    backend.push({"left": 1})
    assert "right" not in ctrl.programs[-1]  # at rest: it waits (the controller's "stay")
    assert ctrl.tcp_xyz() == YUMI_REST
    backend.close()
    assert ctrl.closed


def test_a_picture_with_an_arm_in_view_is_taken_again(tmp_path: Path) -> None:
    backend, ctrl = make_yumi(tmp_path, [twin_picture(0)])
    ctrl.park_in_view("left", reads=2)  # the picture's read and the move's
    n = len(ctrl.programs)
    views = backend.observe()
    assert backend.retaken == 1
    # on a straight leg over its box (its joints the model's there, the pusher down):
    # straight up to travel height where it is, straight to the gate's point, by joints
    # to the gate joints (the correction), by joints to rest
    cal = backend._arms["left"].calibration
    assert [(w.kind, w.xyz_mm) for w in ctrl.programs[n]["left"]] == [
        ("move_l", (*YUMI_IN_VIEW[:2], 90.0)), ("move_l", (*cal.gate_xy, 100.0)),
        ("abs_j", None), ("rest", None)]
    assert ctrl.programs[n]["left"][2].joints_deg == cal.gate_joints_deg
    assert not views["left"].violating
    ctrl.stuck.add("right")  # over the other arm's table (outside its own box): unknown
    n = len(ctrl.programs)
    with pytest.raises(BackendError, match=r"^arm right is where the driver will not move "
                                           r"it from: joints \[.*\] deg, the pusher's tip "
                                           r"at \(360, -200, 50\) mm; .*the tip is outside "
                                           r"the table box.*nothing was sent: jog it to rest "
                                           r"on the FlexPendant \(manual reduced speed\), "
                                           r"then PP to Main$"):
        backend.observe()
    assert len(ctrl.programs) == n  # refused before anything was sent


def test_violation_refusal_and_the_reset_recheck(tmp_path: Path) -> None:
    out_left = twin_picture(1, {"left": (0.02, 0.5)})
    back_in = twin_picture(1, {"left": (0.5, 0.45)})
    # Frames in order: start (cube out), reset check (still out), reset check (back in).
    backend, ctrl = make_yumi(tmp_path, [out_left, out_left, back_in])
    views = backend.observe()
    assert views["left"].violating and not views["right"].violating
    n = len(ctrl.programs)
    assert backend.push({"left": 1}) == {  # refused, with the reason: no motion
        "left": ArmOutcome(False, False, refused="arm is violating: waiting for a hard reset")}
    assert len(ctrl.programs) == n
    assert backend.reset(["left"]) == {"left": False}  # the picture says: still out
    assert backend.reset(["left"]) == {"left": True}  # now it is back
    goal = backend.observe()["left"].goal
    assert math.dist(goal, (0.5, 0.45)) >= MIN_GOAL_DISTANCE - 0.02


def test_success_is_judged_from_the_picture_and_gives_a_new_goal(tmp_path: Path) -> None:
    probe, _ = make_yumi(tmp_path, [twin_picture(2, {"left": (0.5, 0.5)})], seed=7,
                         name="probe")
    goal = probe.observe()["left"].goal
    probe.close()
    start = twin_picture(2, {"left": (0.5, 0.5)})
    at_goal = twin_picture(2, {"left": goal})
    backend, _ = make_yumi(tmp_path, [start, at_goal], seed=7)
    assert backend.observe()["left"].goal == goal  # same seed, same picture: same goal
    out = backend.push({"left": 0})
    assert out["left"].success and not out["left"].violation
    assert backend.observe()["left"].goal != goal  # a soft reset: a new goal


def test_goal_is_drawn_into_the_image_like_the_twin(tmp_path: Path) -> None:
    from testbed.perception import cube as perception

    backend, _ = make_yumi(tmp_path, [twin_picture(4)])
    v = backend.observe()["right"]
    found = perception.find_goal(v.image)
    assert found is not None and math.dist(found, v.goal) < 1.5 / 64


# -- issue 43: where an arm is, judged in joint space; the gate a measured joint target ----
def fake_on(tmp_path: Path, **over: object) -> tuple[YumiBackend, FakeYumiController]:
    """:func:`make_yumi`'s backend, its left arm's calibration changed by ``over`` (a key
    set to None is left out of the file)."""
    backend, ctrl = make_yumi(tmp_path, [twin_picture(0)])
    cal = {k: v for k, v in {**yumi_calibration("left"), **over}.items() if v is not None}
    left = ArmSetup("left", YUMI_CROPS["left"], False, ArmCalibration.from_dict(cal, "left"))
    return YumiBackend([left, backend._arms["right"]], backend._camera, ctrl), ctrl


def leg_pose(xyz: tuple[float, float, float]) -> tuple[float, ...]:
    """The left arm's joints (the fake cell's left is a T_ROB_R) with its pusher down at
    ``xyz``, the arm angle held: where a stopped leg leaves it."""
    got = yumi_joints("left")("left", xyz)
    assert got is not None
    return tuple(got)


def test_at_rest_is_judged_from_the_joints_within_the_tolerance(tmp_path: Path) -> None:
    backend, ctrl = fake_on(tmp_path)
    rest = backend._arms["left"].calibration.pose.rest_joints_deg  # type: ignore[union-attr]
    near = (rest[0] + 0.5 * JOINT_TOLERANCE_DEG, *rest[1:6], rest[6] - 0.5 * JOINT_TOLERANCE_DEG)
    ctrl.place("left", YUMI_REST["left"], near)
    backend.rest()
    assert ctrl.programs == []  # at rest: the way to rest is no move at all
    off = (rest[0] + 2 * JOINT_TOLERANCE_DEG, *rest[1:])  # the same tip, within a mm
    ctrl.place("left", YUMI_REST["left"], off)
    with pytest.raises(BackendError, match=r"^arm left is where the driver will not move "
                                           r"it from: joints \[-39\.8, -90\.0, .*not at rest "
                                           r"nor at its gate \(every joint within 0\.1 deg\).*"
                                           r"nothing was sent: jog it to rest on the "
                                           r"FlexPendant \(manual reduced speed\), then PP "
                                           r"to Main$"):
        backend.rest()
    assert ctrl.programs == []
    with pytest.raises(BackendError, match=r"^arm left is where"):
        backend.push({"left": 0, "right": 1})  # a push too: nothing for either arm
    assert ctrl.programs == []


def test_an_arm_at_an_unknown_pose_is_refused_with_nothing_sent(tmp_path: Path) -> None:
    backend, ctrl = fake_on(tmp_path)
    inside = (360.0, -200.0, 50.0)  # over its own table box, below clear height
    q = leg_pose(inside)
    turned = (q[0], q[1], q[2], q[3], q[4] + 60.0, q[5], q[6])  # the pusher tilted 60 deg
    ctrl.place("left", inside, turned)
    with pytest.raises(BackendError, match=r"the pusher points \d+ deg from the legs' "
                                           r"direction .*nothing was sent: jog it to rest"):
        backend.rest()
    outside = (300.0, -20.0, 50.0)  # beyond its box's inner edge, below clear height
    ctrl.place("left", outside, leg_pose(outside))
    with pytest.raises(BackendError, match=r"the tip is outside the table box"):
        backend.move_tcp("left", (300.0, -200.0, 40.0))
    high = (360.0, -200.0, 150.0)  # over its box, above clear height: no leg goes there
    ctrl.place("left", high, leg_pose(high))
    with pytest.raises(BackendError, match=r"the tip is not between the table and clear "
                                           r"height 100 mm"):
        backend.rest()
    assert ctrl.programs == []


def test_an_arm_stopped_on_a_leg_goes_back_by_the_gate(tmp_path: Path) -> None:
    backend, ctrl = fake_on(tmp_path)
    cal = backend._arms["left"].calibration
    low = (400.0, -150.0, 12.0)  # where a stopped push leaves it
    ctrl.place("left", low, leg_pose(low))
    backend.rest()
    assert [(w.kind, w.xyz_mm, w.joints_deg) for w in ctrl.programs[-1]["left"]] == [
        ("move_l", (400.0, -150.0, 90.0), None), ("move_l", (*cal.gate_xy, 100.0), None),
        ("abs_j", None, cal.gate_joints_deg), ("rest", None, None)]
    ctrl.place("left", low, leg_pose(low))  # and a push from there: back to the gate
    backend.move_tcp("left", (300.0, -250.0, 90.0))  # joints, then on as from rest
    assert [w.kind for w in ctrl.programs[-1]["left"]] == ["move_l", "move_l", "abs_j",
                                                          "move_l"]
    assert ctrl.programs[-1]["left"][2].joints_deg == cal.gate_joints_deg


def test_a_calibration_without_gate_joints_is_refused_naming_the_field(
        tmp_path: Path) -> None:
    backend, ctrl = fake_on(tmp_path, gate_joints_deg=None)
    backend.observe()
    out = backend.push({"left": 0})
    err = out["left"].error
    assert err is not None and "'gate_joints_deg'" in err and "run testbed calibrate" in err
    assert "\n" not in err
    assert ctrl.programs == []  # nothing sent
    with pytest.raises(BackendError, match=r"^arm left: its calibration has no "
                                           r"'gate_joints_deg' \(the gate's joints\): nothing "
                                           r"is sent; run testbed calibrate"):
        backend.move_tcp("left", (300.0, -200.0, 40.0))
    backend.rest()  # at rest: nothing to do, nothing refused
    assert ctrl.programs == []


def test_gate_joints_that_are_not_at_the_gate_are_refused(tmp_path: Path) -> None:
    gate = yumi_calibration("left")["gate_joints_deg"]
    backend, ctrl = fake_on(tmp_path, gate_joints_deg=[gate[0] + 10.0, *gate[1:]])
    with pytest.raises(BackendError, match=r"^arm left: gate_joints_deg \[.*\] put the "
                                           r"pusher's tip at \(.*\) mm \(the model\), \d+ mm "
                                           r"from the gate .*\(want 10 mm\); nothing was "
                                           r"moved: run testbed calibrate"):
        backend.move_tcp("left", (300.0, -200.0, 40.0))
    assert ctrl.programs == []


def test_gate_joints_at_another_arm_angle_are_refused_before_anything_moves(
        tmp_path: Path) -> None:
    """Issue 43: gate joints that put the pusher at the gate with the elbow at another arm
    angle than the calibration's (what a controller with another Arm-Angle Reference
    Direction measures at calibration, for the robtarget the driver sent) mean every
    robtarget the driver sends would be solved into an elbow nobody swept: refused, named,
    nothing sent (the layout check FAULTs the same: test_yumi_paths_zones.py)."""
    from drivers.yumi.gate import calibration_gate_joints

    cal = yumi_calibration("left")  # the fake cell's "left" is a T_ROB_R: arm angle +40
    assert cal["arm_angle_deg"] == 40.0
    other = calibration_gate_joints("left", {**cal, "arm_angle_deg": 15.0})
    backend, ctrl = fake_on(tmp_path, gate_joints_deg=other)
    with pytest.raises(BackendError, match=r"^arm left: gate_joints_deg \[.*\] hold the elbow "
                                           r"at arm angle 15\.0 deg \(the driver's model, its "
                                           r"reference along axis 1\), not the calibration's "
                                           r"arm_angle_deg 40: the controller's Arm-Angle "
                                           r"Reference Direction differs"):
        backend.move_tcp("left", (300.0, -200.0, 40.0))
    assert ctrl.programs == []


def test_rws_adapter_builds_multimove_rapid_without_a_controller(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # the fake cell's "left" box is at y < 0: the IRB 14000's right arm (driver_fakes._fake_side)
    poses = {"left": ArmPose("T_ROB_R", "ROB_R", (-40, -90, 30, 0, 40, 0, -135),
                             tool_z_mm=184.2, arm_angle_deg=40.0),
             "right": ArmPose("T_ROB_L", "ROB_L", (40, -90, 30, 0, 40, 0, 135),
                              tool_z_mm=184.2)}
    ctrl = RwsYumiController("http://127.0.0.1:1", poses, motion_timeout_s=0.3,
                             login=FACTORY_LOGIN)
    wps = plan_push(setup("left"), (0.5, 0.5), 0.0, 3)
    rapid = ctrl.program("left", wps).get_program_rapid()
    # no MoveJ: the gate (twice: from rest, and the correction) and rest are MoveAbsJ
    assert rapid.count("MoveL") == 5 and "MoveJ " not in rapid and rapid.count("MoveAbsJ") == 3
    flat = rapid.replace(" ", "")  # the shipped tool: its frame and tool_pusher's load
    assert "[[0,0,184.2],[1,0,0,0]],[0.272,[7.5,11.5,53.8],[1,0,0,0],0.0003,0.00032," \
           "9e-05]" in flat or "0.00009]" in flat, flat
    assert "[40,100,1000,100]" in rapid.replace(" ", "").replace(".0", "")
    calls: list[tuple[object, ...]] = []

    class Rws:  # the RWS calls of our execute path, recorded; RAPID never ends
        state = "stopped"

        def get_execution_state(self) -> SimpleNamespace:
            return SimpleNamespace(ctrlexecstate=self.state)

        def get_controller_state(self) -> str:
            return "motoron"

        def get_operation_mode(self) -> str:
            return "AUTO"

        def get_speedratio(self) -> float:
            return 100.0

        def read_event_log(self) -> list[SimpleNamespace]:  # zones on since the restart
            return [SimpleNamespace(seqnum=5, code=10002, msgtype=1, title="PP reset",
                                    args=[], desc="")] + [
                SimpleNamespace(seqnum=4 - i, code=80003, msgtype=1, title=ZONES_ACTIVE,
                                args=[ZONES_ACTIVE, t, "zones 5", "now"], desc="")
                for i, t in enumerate(("T_ROB_L", "T_ROB_R"))] + [
                SimpleNamespace(seqnum=2, code=10045, msgtype=1, title="System restarted",
                                args=[], desc="")]

        def get_rapid_variable(self, var: str, task: str) -> str:
            assert var == "TestbedMotion/TB_RAPID_VERSION", var
            return str(RAPID_VERSION)

        def resetpp(self) -> None:
            calls.append(("resetpp",))

        def activate_task(self, task: str) -> None:
            calls.append(("activate", task))

        def get_ramdisk_path(self) -> str:
            return "$TEMP"

        def upload_file(self, name: str, data: bytes) -> None:
            calls.append(("upload", name))

        def start(self, cycle: str, tasks: list[str]) -> None:
            calls.append(("start", cycle, tasks))
            self.state = "running"

        def stop(self) -> None:
            calls.append(("stop",))

    monkeypatch.setattr(ctrl, "_rws", Rws())
    with pytest.raises(BackendError, match=r"did not finish within motion_timeout_s = 0\.3 s"):
        ctrl.execute({"left": wps, "right": [Waypoint("rest", None, 100.0)]})
    assert calls == [("activate", "T_ROB_R"), ("activate", "T_ROB_L"), ("resetpp",),
                     ("upload", "$TEMP/testbed_T_ROB_R.bin"),
                     ("upload", "$TEMP/testbed_T_ROB_L.bin"),
                     ("start", "once", ["T_ROB_R", "T_ROB_L"]), ("stop",)]
    # one arm's program (calibration's move_tcp): the other task still gets a file, a
    # "stay", is activated before the program pointers are reset, and starts: it never
    # replays what its RAM disk held (issue 35)
    calls.clear()
    ctrl._rws.state = "stopped"
    with pytest.raises(BackendError, match=r"did not finish within"):
        ctrl.execute({"left": wps})
    assert calls[:6] == [("activate", "T_ROB_R"), ("activate", "T_ROB_L"), ("resetpp",),
                         ("upload", "$TEMP/testbed_T_ROB_R.bin"),
                         ("upload", "$TEMP/testbed_T_ROB_L.bin"),
                         ("start", "once", ["T_ROB_R", "T_ROB_L"])]
    stay = ctrl.stay("T_ROB_R").get_program_rapid()
    assert "WaitTime" in stay and "Move" not in stay and "184.2" in stay


def test_yumi_agent_with_an_unreachable_controller_faults_clearly(tmp_path: Path) -> None:
    video = write_video(tmp_path / "cam.avi", [twin_picture(0)])
    arms = []
    for arm in ("left", "right"):
        cal = tmp_path / f"{arm}.json"
        cal.write_text(json.dumps(yumi_calibration(arm)))
        arms.append(ArmConfig(name=arm, crop=YUMI_CROPS[arm], mirror=arm == "right",
                              calibration=str(cal)))
    host = local_host("yumi0", backend="yumi", camera=str(video),
                      controller_url="http://127.0.0.1:9", arms=arms,
                      credentials_file=FACTORY_DEFAULT)
    with HostFleet([host]) as fleet:
        assert fleet.host_status()["yumi0"].connected  # the agent started; the robot is away
        obs = fleet.observe()
    f = obs["yumi0/left"]
    assert isinstance(f, Fault) and "cannot read the arms' positions" in f.reason
    assert f.traceback == ""  # a BackendError: one line, no traceback
    assert not isinstance(obs["yumi0/right"], ArmObservation)
    assert np.all([isinstance(o, Fault) for o in obs.values()])


def test_reseed_gives_the_goals_of_a_fresh_backend_with_that_seed(tmp_path: Path) -> None:
    pictures = [twin_picture(5)]
    fresh, _ = make_yumi(tmp_path, pictures, seed=9, name="fresh")
    want = {a: v.goal for a, v in fresh.observe().items()}
    fresh.close()
    backend, _ = make_yumi(tmp_path, pictures, seed=0)
    first = {a: v.goal for a, v in backend.observe().items()}
    backend.reseed(9)
    assert {a: v.goal for a, v in backend.observe().items()} == want != first
    backend.close()


def test_a_push_point_off_the_homography_is_an_error_not_a_clipped_waypoint() -> None:
    cal = yumi_calibration("left")
    # w = 1 - (u + 0.5)/128 vanishes on u = 127.5: the crop's centre line (pixel centres
    # at integers, so the crop's edge is at -0.5)
    cal["homography"] = [[0.0, 1.25, 200.0], [1.25, 0.0, -360.0],
                         [-1 / 128, 0.0, 1.0 - 0.5 / 128]]
    arm = ArmSetup("left", YUMI_CROPS["left"], False, ArmCalibration.from_dict(cal, "left"))
    with pytest.raises(BackendError, match=r"arm left: push point .* non-finite"):
        plan_push(arm, (0.5 + (8 / 64 + 4 / 64), 0.5), 0.0, 3)


def test_calibration_mode_build_errors_and_provisional_box(tmp_path: Path) -> None:
    from drivers.yumi.arm_calibration import SHIPPED_TABLE_BOX_MM
    from drivers.yumi.backend import build_yumi_backend

    video = str(write_video(tmp_path / "cam.avi", [twin_picture(0)]))
    right = tmp_path / "right.json"
    right.write_text(json.dumps(yumi_calibration("right")))
    rest_only = tmp_path / "left-rest.json"  # what a lab writes before calibrating
    rest_only.write_text(json.dumps({"rest_joints_deg": [40, -90, 30, 0, 40, 0, 135],
                                     "tool_z_mm": 184.2}))
    url = "http://127.0.0.1:9"

    def build(left: Path, calibrating: list[str]) -> YumiBackend:
        cals = {"left": str(left), "right": str(right)}
        return build_yumi_backend(["left", "right"], [False, True], YUMI_CROPS, cals, video,
                                  url, calibrating=calibrating,
                                  credentials_file=FACTORY_DEFAULT)

    with pytest.raises(BackendError, match=r"--calibrate middle: no such arm"):
        build(rest_only, ["middle"])
    with pytest.raises(BackendError, match=r"arm left: cannot read calibration"):
        build(tmp_path / "none-yet.json", [])  # not calibrating: the file must exist
    with pytest.raises(BackendError, match=r"arm left: calibration .*none-yet.json has no "
                                           r"'tool_z_mm' and the controller's tool_pusher "
                                           r"of T_ROB_L cannot be read: .*4-point TCP"):
        build(tmp_path / "none-yet.json", ["left"])  # no file, no controller: no tool
    backend = build(rest_only, ["left"])
    # no table box in the file: the shipped one of its side (issue 44), where its gate is
    assert backend._arms["left"].calibration.table_box_mm == SHIPPED_TABLE_BOX_MM["left"]
    with pytest.raises(BackendError, match="arm left is being calibrated"):
        backend.push({"right": 0})
    assert backend.frame().shape == (256, 576, 3)
    with pytest.raises(ValueError, match="unknown arm"):
        backend.move_tcp("middle", (0, 0, 0))
    backend.close()
