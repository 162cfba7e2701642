"""The ABB YuMi (IRB 14000) host: two arms, one overhead camera, one controller.

Why it looks like this: the policy acts in the arm's canonical 64x64 image frame, the
robot moves in millimetres in the robot's world frame (wobj0). A per-arm calibration
file holds the image-to-table homography that joins the two, plus the safety envelope (a table box
every waypoint is clipped into, a speed cap, push and travel heights) and the rest pose
out of the camera's view. The task bookkeeping the twin does in simulation (goal drawn
into the image, success, violation, soft reset after success or 50 pushes) is done
here from the picture, with ``testbed.perception.cube`` (imported lazily: the agent on a
robot host needs numpy and cv2 only).

One push, per arm (all arms' programs run at once, MultiMove)::

    canonical face k, cube pose (perception) --start/end in canonical units-->
    crop pixel --(mirror, crop box)--> camera pixel --homography--> table mm
    --clip to the table box--> waypoints: the gate joints (MoveAbsJ), above start,
    down, stroke, up, the gate, rest pose (``paths.py``)

Before anything is sent, where each arm is, is judged from the joints the controller
reports (``arm_place.py``): at rest, at its gate, on a straight leg over its table box
(it goes back by the gate first), or refused with the fix (jog it to rest); a
calibration without the gate's joints (``gate_joints_deg``) moves nothing
(``gate.py``).

A picture is only taken with every TCP outside the camera's view; if an arm is in view
(before or after the shot) it is sent to rest and the picture is taken again.

A push the backend cannot make is *refused* with the reason (the cube not found in this
picture, the arm violating), never reported as a push; a push that cannot be planned for
one arm is that arm's *error* while the other arms' programs still run. Which controller
client drives the arms (the real controller's RWS, the hardware twin) is chosen from the
controller URL in :func:`~drivers.yumi.controllers.make_controller`, so nothing
here knows the twin.

Calibration mode (``build_yumi_backend(..., calibrating=[arm])``): that arm may have no
calibration file yet, or one without a homography; it gets a provisional calibration,
and only ``frame``, ``move_tcp``, ``rest`` and ``save_calibration`` work (observe, push
and reset need the homography, so they are errors naming the arm). Its gate's joints are
measured there (:meth:`YumiBackend._measure_gate`) for ``testbed calibrate`` to write.

Over 450 lines, on purpose: ``YumiBackend`` is one host's observe, push, reset and rest
over a camera and a controller both arms share; what could leave it has (the calibration
file: ``arm_calibration.py``, the paths: ``paths.py``, where an arm is: ``arm_place.py``,
the gate: ``gate.py``, the controller's state: ``controller_state.py``).
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from drivers.backends.base import ArmOutcome, ArmView, HostBackend
from drivers.cameras.camera import Camera, expand_path, is_url
from drivers.errors import BackendError
from drivers.yumi.arm_calibration import (
    ArmCalibration,
    layout_keys,
    provisional_calibration,
    tool_of,
    write_atomic,
)
from drivers.yumi.arm_place import ArmRoom, Place, place_of
from drivers.yumi.gate import GATE_HOW, arm_tool, gate_problem
from drivers.yumi.paths import back_to_gate, leave_rest, to_rest
from drivers.yumi.yumi_controller import Waypoint, YumiControllerClient
from testbed.core.types import (
    FACE_DIRECTIONS,
    IMAGE_SIZE,
    MAX_PUSHES_PER_GOAL,
    MIN_GOAL_DISTANCE,
)

GOAL_RGB = (40, 200, 40)
"""Same goal disc as the twin (sim_twin.constants.GOAL_RGB, GOAL_RADIUS = 3/64)."""
GOAL_RADIUS = 3.0 / 64.0
GOAL_MARGIN = 0.12
CUBE_HALF = 4.0 / 64.0
LIFT_TOLERANCE_MM = 1.0
"""A pusher this far below travel height counts as up (the controller's own jitter)."""
log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class ArmSetup:
    name: str
    crop: tuple[int, int, int, int]
    """(x0, y0, x1, y1) of the arm's workspace in the camera picture."""
    mirror: bool
    calibration: ArmCalibration

    def canonical_to_pixel(self, c: Sequence[float]) -> tuple[float, float]:
        x0, y0, x1, y1 = self.crop
        cx = 1.0 - c[0] if self.mirror else c[0]
        # OpenCV's pixel centres are at integers: the crop's edge is half a pixel before
        # x0, so canonical 0 is at x0 - 0.5 (the calibration's homography uses centres).
        return (x0 - 0.5 + cx * (x1 - x0), y0 - 0.5 + c[1] * (y1 - y0))

    def canonical_to_table(self, c: Sequence[float]) -> tuple[float, float]:
        return self.calibration.pixel_to_table(*self.canonical_to_pixel(c))


def plan_push(arm: ArmSetup, centre: Sequence[float], yaw: float, face: int) -> list[Waypoint]:
    """Waypoints of one push: face ``face`` of a cube at ``centre`` (canonical), ``yaw`` rad.

    Object-centric: the pusher comes in along the face's real normal, the canonical face
    direction turned by the cube's yaw. Every point is clipped into the table box and
    every speed capped; the program ends in the rest pose, out of the camera's view.
    """
    cal = arm.calibration
    dx, dy = FACE_DIRECTIONS[face]
    c, s = math.cos(yaw), math.sin(yaw)
    d = (c * dx - s * dy, s * dx + c * dy)
    back = CUBE_HALF + cal.start_offset
    start = (centre[0] - d[0] * back, centre[1] - d[1] * back)
    end = (start[0] + d[0] * cal.stroke, start[1] + d[1] * cal.stroke)
    bx0, by0, bx1, by1 = cal.table_box_mm

    def table(p: Sequence[float], z: float) -> tuple[float, float, float]:
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = arm.canonical_to_table(p)
        if not (math.isfinite(x) and math.isfinite(y)):  # clipping would hide a bad homography
            raise BackendError(f"arm {arm.name}: push point {tuple(p)} maps to a non-finite "
                               f"table point; check the calibration's homography")
        return (min(max(x, bx0), bx1), min(max(y, by0), by1), z)

    vmax = cal.max_speed_mm_s
    vpush = min(cal.push_speed_mm_s, vmax)
    s_xy, e_xy = table(start, 0.0)[:2], table(end, 0.0)[:2]
    gate = gate_joints_of(arm.name, cal)
    return [*leave_rest(gate, s_xy, cal.z_travel_mm, vmax),
            Waypoint("move_l", (*s_xy, cal.z_push_mm), min(vmax, 2 * vpush)),
            Waypoint("move_l", (*e_xy, cal.z_push_mm), vpush),
            Waypoint("move_l", (*e_xy, cal.z_travel_mm), min(vmax, 2 * vpush), fine=False),
            *to_rest(cal.gate_xy, gate, cal.z_clear_mm, vmax)]


def gate_joints_of(arm: str, cal: ArmCalibration) -> tuple[float, ...]:
    """The calibration's gate joints, or a :class:`BackendError` of one line naming the
    field and the fix: no program leaves rest without them (``drivers/yumi/paths.py``)."""
    if cal.gate_joints_deg is None:
        raise BackendError(f"arm {arm}: its calibration has no 'gate_joints_deg' (the "
                           f"gate's joints): nothing is sent; {GATE_HOW}")
    return cal.gate_joints_deg


def in_view_faults(info: Mapping[str, Any]) -> list[str]:
    """The check's FAULT reasons for the arms a ``describe`` answer found in the camera's
    view (``in_view``), each with the fix: the check moves nothing, a person jogs the
    arm to rest (an arm there would be sent to rest by the next picture step, in Auto,
    before anything has judged the controller)."""
    out = []
    for arm, xyz in sorted((info.get("in_view") or {}).items()):
        x, y, z = (float(c) for c in xyz)
        out.append(f"arm {arm} is in the camera's view at ({x:.0f}, {y:.0f}, {z:.0f}) mm: "
                   f"jog it to rest on the FlexPendant, then check again")
    return out


class YumiBackend(HostBackend):
    """Two YuMi arms under one camera; the controller client is injected."""

    kind = "yumi"

    def __init__(self, arms: Sequence[ArmSetup], camera: Camera,
                 controller: YumiControllerClient, *, seed: int = 0,
                 perception: Any = None, retakes: int = 3,
                 calibration_paths: Mapping[str, str] | None = None,
                 calibrating: Collection[str] = ()) -> None:
        if not arms:
            raise BackendError("a YuMi host needs at least one arm")
        self._arms = {a.name: a for a in arms}
        if unknown := sorted(set(calibrating) - set(self._arms)):
            raise BackendError(f"cannot calibrate arm(s) {unknown}: this host has "
                               f"{list(self._arms)}")
        self._calibrating = frozenset(calibrating)
        self._cal_paths = dict(calibration_paths or {})
        self._camera = camera
        self._controller = controller
        self._perception = perception
        self._retakes = retakes
        self._rng = np.random.default_rng(seed)
        self._goal: dict[str, tuple[float, float] | None] = dict.fromkeys(self._arms, None)
        self._violating: dict[str, bool | None] = dict.fromkeys(self._arms, None)
        self._pushes = dict.fromkeys(self._arms, 0)
        self._pose: dict[str, Any] = dict.fromkeys(self._arms, None)
        self._gate: dict[str, tuple[float, ...]] = {}
        """The gate joints of each arm being calibrated (:meth:`_measure_gate`)."""
        self._measured_gate: dict[str, tuple[float, ...]] = {}
        """Each arm being calibrated: the joints the controller reported at its gate, for
        ``testbed calibrate`` to write (``describe``'s ``layout``, :meth:`save_calibration`)."""
        self._closed = False
        self.retaken = 0
        """Pictures taken again because an arm was in view (for tests and logs)."""

    @property
    def arm_names(self) -> tuple[str, ...]:
        return tuple(self._arms)

    @property
    def mirror(self) -> tuple[bool, ...]:
        return tuple(a.mirror for a in self._arms.values())

    @property
    def perception(self) -> Any:
        if self._perception is None:
            from testbed.perception import cube  # lazy: see the module docstring

            self._perception = cube
        return self._perception

    def _require_calibrated(self) -> None:
        """Pictures need every arm's homography (an arm's TCP in view is judged with it)."""
        for arm in self._arms:
            if arm in self._calibrating:
                err = BackendError(f"arm {arm} is being calibrated: observe, push and reset "
                                   f"work once the agent restarts with its new calibration")
                err.arm = arm  # type: ignore[attr-defined]
                raise err

    # -- pictures --------------------------------------------------------------------
    def _in_view(self) -> dict[str, tuple[float, float, float]]:
        """Each arm whose TCP is in the camera's view (2 % margin), with where it is (mm):
        read-only, one read of the controller's TCPs."""
        w, h = self._camera.size
        tcp = self._controller.tcp_xyz()
        out: dict[str, tuple[float, float, float]] = {}
        for name, arm in self._arms.items():
            u, v = arm.calibration.table_to_pixel(*tcp[name][:2])
            if -0.02 * w <= u <= 1.02 * w and -0.02 * h <= v <= 1.02 * h:
                x, y, z = (float(c) for c in tcp[name])
                out[name] = (x, y, z)
        return out

    def _arms_in_view(self) -> list[str]:
        return list(self._in_view())

    def _picture(self) -> npt.NDArray[np.uint8]:
        for _ in range(self._retakes + 1):
            if in_view := self._arms_in_view():
                self._move({a: [Waypoint("rest", None, self._arms[
                    a].calibration.max_speed_mm_s)] for a in in_view})
                self.retaken += 1
                continue
            frame = self._camera.read()
            if self._arms_in_view():  # something moved into view during the shot
                self.retaken += 1
                continue
            return frame
        raise BackendError(f"no picture without an arm in view after {self._retakes + 1} "
                           f"tries; check the rest poses and the calibration")

    def _crop(self, frame: npt.NDArray[np.uint8], arm: ArmSetup) -> npt.NDArray[np.uint8]:
        import cv2

        x0, y0, x1, y1 = arm.crop
        fh, fw = frame.shape[:2]
        if x1 > fw or y1 > fh:
            raise BackendError(f"arm {arm.name}: crop {arm.crop} exceeds the {fw}x{fh} picture")
        img = cv2.resize(frame[y0:y1, x0:x1], (IMAGE_SIZE, IMAGE_SIZE),
                         interpolation=cv2.INTER_AREA)
        img = img[:, ::-1, ::-1] if arm.mirror else img[:, :, ::-1]
        return np.ascontiguousarray(img)

    def _look(self) -> dict[str, npt.NDArray[np.uint8]]:
        frame = self._picture()
        crops: dict[str, npt.NDArray[np.uint8]] = {}
        for name, arm in self._arms.items():
            crops[name] = self._crop(frame, arm)
            self._pose[name] = self.perception.find_cube(crops[name])
        return crops

    def _out(self, arm: str) -> bool:
        pose = self._pose[arm]
        return pose is None or bool(self.perception.is_violation(pose))

    def _new_goal(self, arm: str) -> None:
        import cv2

        poly = np.asarray(self.perception.WORKSPACE_POLYGON, np.float32).reshape(-1, 1, 2)
        pose = self._pose[arm]
        cube = np.asarray(pose.centre if pose is not None else (0.5, 0.5))
        lo, hi = poly.reshape(-1, 2).min(0), poly.reshape(-1, 2).max(0)
        for _ in range(500):
            g = self._rng.uniform(lo, hi)
            inside = cv2.pointPolygonTest(poly, (float(g[0]), float(g[1])), True) >= GOAL_MARGIN
            if inside and np.hypot(*(g - cube)) >= MIN_GOAL_DISTANCE:
                self._goal[arm] = (float(g[0]), float(g[1]))
                self._pushes[arm] = 0
                return
        raise BackendError(f"arm {arm}: no goal found in the workspace")

    def _draw_goal(self, img: npt.NDArray[np.uint8], goal: tuple[float, float]
                   ) -> npt.NDArray[np.uint8]:
        import cv2

        out = img.copy()
        k = 16  # 4 sub-pixel bits
        cv2.circle(out, (round(goal[0] * IMAGE_SIZE * k), round(goal[1] * IMAGE_SIZE * k)),
                   round(GOAL_RADIUS * IMAGE_SIZE * k), GOAL_RGB, -1, cv2.LINE_AA, 4)
        return out

    # -- HostBackend -----------------------------------------------------------------
    def observe(self) -> dict[str, ArmView]:
        self._require_calibrated()
        crops = self._look()
        views: dict[str, ArmView] = {}
        for arm in self._arms:
            if self._violating[arm] is None:  # first look since start: judge the picture
                self._violating[arm] = self._out(arm)
            goal = self._goal[arm]
            if goal is None:
                self._new_goal(arm)
                goal = self._goal[arm]
            assert goal is not None
            views[arm] = ArmView(self._draw_goal(crops[arm], goal), bool(self._violating[arm]),
                                 goal, None)
        return views

    def push(self, faces: Mapping[str, int]) -> dict[str, ArmOutcome]:
        faces = self.check_faces(faces)
        self._require_calibrated()
        if any(self._pose[a] is None and self._violating[a] is None for a in faces):
            self.observe()
        moving = {a: f for a, f in faces.items()
                  if not self._violating[a] and self._pose[a] is not None}
        programs: dict[str, list[Waypoint]] = {}
        errors: dict[str, str] = {}
        for name, arm in self._arms.items():
            if name in moving:
                pose = self._pose[name]
                try:
                    programs[name] = plan_push(arm, pose.centre, float(pose.yaw), moving[name])
                    continue
                except Exception as exc:  # this arm only: its siblings still push
                    errors[name] = f"cannot plan the push: {type(exc).__name__}: {exc}"
                    log.warning("arm %s: %s", name, errors[name])
                    del moving[name]
            programs[name] = [Waypoint("rest", None, arm.calibration.max_speed_mm_s)]
        took: dict[str, float] = {}
        if moving:
            t0 = time.monotonic()
            self._move(programs)
            took = {"push_s": time.monotonic() - t0}  # the arms' motion, on this host's clock
            self._look()
        out: dict[str, ArmOutcome] = {}
        for arm in faces:
            if arm in errors:
                out[arm] = ArmOutcome(False, False, error=errors[arm])
                continue
            if arm not in moving:  # refused: no cube seen, or violating: nothing moved
                out[arm] = ArmOutcome(False, False, refused=self._refusal(arm))
                continue
            if self._out(arm):
                self._violating[arm] = True
                out[arm] = ArmOutcome(False, True, readings=took)
                continue
            goal = self._goal[arm]
            success = goal is not None and bool(self.perception.is_success(self._pose[arm], goal))
            self._pushes[arm] += 1
            if success or self._pushes[arm] >= MAX_PUSHES_PER_GOAL:
                self._new_goal(arm)  # soft reset: no human needed
            out[arm] = ArmOutcome(success, False, readings=took)
        return out

    def _refusal(self, arm: str) -> str:
        if self._pose[arm] is None:
            return "cube not found"
        return "arm is violating: waiting for a hard reset"

    def reset(self, arms: Sequence[str]) -> dict[str, bool]:
        arms = self.check_arms(arms)
        self._require_calibrated()
        self._look()  # the human put the cube back; believe the picture, not the human
        done: dict[str, bool] = {}
        for arm in arms:
            ok = not self._out(arm)
            if ok:
                self._violating[arm] = False
                self._new_goal(arm)
            done[arm] = ok
        return done

    def rest(self) -> None:
        self._move({name: [Waypoint("rest", None, a.calibration.max_speed_mm_s)]
                    for name, a in self._arms.items()})

    def stop(self) -> None:
        """Stop the motion in progress through the controller (from the agent's control
        path, while ``push``/``rest``/``move_tcp`` waits in another thread)."""
        self._controller.stop()

    def describe(self) -> dict[str, Any]:
        """The controller as ``testbed check`` shows it, with each arm's task and table
        box (which must lie inside the task's world zone box), and the camera: its
        settings as read back and each arm's crop's sharpness and exposure.

        Read-only (issue 43): ``testbed check`` and the check every trial runs first ask
        it before anything has judged the controller, so it never moves an arm. An arm
        in the camera's view is not sent to rest (the picture step would): it is named
        in ``in_view`` (arm -> its TCP, mm), a FAULT of the check
        (:func:`in_view_faults`), and the crops' figures are left out (the arm would be
        in them). In calibration mode the arms have no homography to judge it with."""
        task = {name: a.calibration.pose.task if a.calibration.pose else name
                for name, a in self._arms.items()}
        from drivers.cameras.picture_quality import camera_report

        in_view, frame = self._still_look()
        crops = None if in_view else {n: a.crop for n, a in self._arms.items()}
        return {"controller": self._controller.describe(),
                "in_view": {n: [round(c, 1) for c in xyz] for n, xyz in in_view.items()},
                "table_boxes": {task[n]: list(a.calibration.table_box_mm)
                                for n, a in self._arms.items()},
                "travel_z": {task[n]: a.calibration.z_travel_mm for n, a in self._arms.items()},
                "clear_z": {task[n]: a.calibration.z_clear_mm for n, a in self._arms.items()},
                "tool_z": {task[n]: a.calibration.tool_z_mm for n, a in self._arms.items()},
                "max_speed": {task[n]: a.calibration.max_speed_mm_s
                              for n, a in self._arms.items()},
                "layout": {n: {"task": task[n], **layout_keys(a.calibration),
                               **self._measured(n)} for n, a in self._arms.items()},
                "camera": camera_report(self._camera, crops, frame=frame)}

    def _measured(self, arm: str) -> dict[str, Any]:
        """An arm being calibrated, once at its gate: the joints the controller reported
        there (``gate_joints_deg``) and the gate's point they were read at, which
        ``testbed calibrate`` writes into the file (``testbed/lab/calibrate.py``)."""
        joints = self._measured_gate.get(arm)
        if joints is None:
            return {}
        cal = self._arms[arm].calibration
        return {"gate_joints_deg": [round(float(v), 4) for v in joints],
                "gate_xy_mm": list(cal.gate_xy), "gate_measured": True}

    def _still_look(self) -> tuple[dict[str, tuple[float, float, float]],
                                   npt.NDArray[np.uint8] | None]:
        """(the arms in view, a picture with none in view or None): what ``describe``
        sees without moving anything. A picture is kept only when no arm was in view
        before and after it was taken; in calibration mode: no judgement, no picture
        (``camera_report`` reads the camera itself)."""
        if self._calibrating:
            return {}, None
        before = self._in_view()
        if before:
            return before, None
        frame = self._camera.read()
        after = self._in_view()  # an arm that came into view during the shot
        return after, (None if after else frame)

    def reseed(self, seed: int) -> None:
        """A fresh goal stream from ``seed``, as a newly started agent would have: goals,
        push counts and violations are forgotten and judged again at the next observe."""
        self._rng = np.random.default_rng(seed)
        for arm in self._arms:
            self._goal[arm] = None
            self._violating[arm] = None
            self._pose[arm] = None
            self._pushes[arm] = 0

    def frame(self) -> npt.NDArray[np.uint8]:
        return self._camera.read()

    def move_tcp(self, arm: str, xyz_mm: Sequence[float]) -> tuple[float, float, float]:
        """Calibration: from rest by joints to the gate, straight to above the point at
        travel height, straight down (or up) to it (``drivers/yumi/paths.py``); from the
        previous point straight up and back to the gate first (:meth:`_move`).

        A point outside the arm's table box is refused (ValueError), never clipped: the
        calibration fit needs the TCP where it was asked to be. An arm being calibrated
        goes to its gate alone the first time, and the joints the controller reports
        there are kept for ``testbed calibrate`` to write (:meth:`_measure_gate`).
        """
        if arm not in self._arms:
            raise ValueError(f"unknown arm {arm!r}; this host has {list(self._arms)}")
        try:
            x, y, z = (float(v) for v in xyz_mm)
        except (TypeError, ValueError):
            raise ValueError(f"arm {arm}: xyz_mm must be 3 numbers, got {xyz_mm!r}") from None
        if not all(math.isfinite(v) for v in (x, y, z)):
            raise ValueError(f"arm {arm}: xyz_mm must be finite, got {(x, y, z)}")
        cal = self._arms[arm].calibration
        bx0, by0, bx1, by1 = cal.table_box_mm
        if not (bx0 <= x <= bx1 and by0 <= y <= by1):
            raise ValueError(f"arm {arm}: ({x:g}, {y:g}) mm is outside its table box "
                             f"{cal.table_box_mm}; refusing to move there")
        if z < 0:
            raise ValueError(f"arm {arm}: z = {z:g} mm is below the table top (z = 0)")
        vmax = cal.max_speed_mm_s
        vslow = min(vmax, 2 * cal.push_speed_mm_s)
        gate = self._gate_joints(arm)
        way = leave_rest(gate, (x, y), cal.z_travel_mm, vmax)
        if abs(z - cal.z_travel_mm) > LIFT_TOLERANCE_MM:
            way.append(Waypoint("move_l", (x, y, z), vslow))
        self._move({arm: way})
        return self._controller.tcp_xyz()[arm]

    def _gate_joints(self, arm: str) -> tuple[float, ...]:
        """The arm's gate joints: its calibration's, or for an arm being calibrated the
        ones measured at its gate (:meth:`_measure_gate`)."""
        if arm in self._calibrating:
            if arm not in self._gate:
                self._measure_gate(arm)
            return self._gate[arm]
        return gate_joints_of(arm, self._arms[arm].calibration)

    def _measure_gate(self, arm: str) -> None:
        """An arm being calibrated goes to its gate alone and the joints the controller
        reports there (``get_jointtarget``) are its gate joints from then on, and what
        ``testbed calibrate`` writes (``describe``'s ``layout``, :meth:`save_calibration`).
        There: by its file's gate joints (MoveAbsJ) when they are at the gate of this
        calibration; else by a MoveJ to the gate's point, the one joint move whose end
        the controller chooses (its own inverse kinematics and arm angle: the joints a
        robot really holds there, whatever the model says), which is then measured and
        is, from rest, the very joint path every later MoveAbsJ to those joints runs;
        ``testbed calibrate`` sweeps it (its layout check) before anything else moves."""
        cal = self._arms[arm].calibration
        vmax = cal.max_speed_mm_s
        tool = arm_tool(arm, cal)
        mine = cal.gate_joints_deg
        if mine is not None and (tool is None or gate_problem(
                tool, mine, cal.gate_xyz, cal.table_box_mm) is None):
            first = leave_rest(mine, cal.gate_xy, cal.z_travel_mm, vmax)[:1]
        else:
            first = [Waypoint("move_j", cal.gate_xyz, vmax)]
        self._move({arm: first})
        self._gate[arm] = self._measured_gate[arm] = tuple(
            float(v) for v in self._controller.joints()[arm])

    def _room(self, arm: str) -> ArmRoom:
        cal = self._arms[arm].calibration
        if cal.pose is None:
            raise BackendError(f"arm {arm}: its calibration has no 'rest_joints_deg'")
        gate = self._gate.get(arm, cal.gate_joints_deg)
        return ArmRoom(cal.pose.rest_joints_deg, gate, cal.table_box_mm, cal.z_clear_mm,
                       arm_tool(arm, cal))

    def _way(self, arm: str, place: Place, wps: Sequence[Waypoint]) -> list[Waypoint]:
        """The program ``arm`` runs from ``place`` for ``wps``, which is written from rest
        (the joint move to the gate first) or is the way to rest (``[rest]``): from rest
        as written (the way to rest: nothing); from the gate as written (its first
        MoveAbsJ is to where the arm is), or straight to rest; from a straight leg, back
        to the gate joints first (``paths.back_to_gate``), then the program from there."""
        to_rest_only = bool(wps) and wps[0].kind == "rest"
        if place.kind == "rest":
            return [] if to_rest_only else list(wps)
        if place.kind == "gate":
            return list(wps[:1]) if to_rest_only else list(wps)
        cal = self._arms[arm].calibration
        gate = self._room(arm).gate_joints_deg
        assert gate is not None  # a leg needs them (arm_place)
        vmax = cal.max_speed_mm_s
        back = back_to_gate(place.tcp_mm, cal.gate_xy, gate, cal.z_travel_mm, cal.z_clear_mm,
                            vmax, min(vmax, 2 * cal.push_speed_mm_s), LIFT_TOLERANCE_MM)
        if to_rest_only:
            return [*back, *wps]
        return [*back, *wps[1:]]  # the program's MoveAbsJ to the gate: where back ends

    def _move(self, programs: Mapping[str, Sequence[Waypoint]]) -> None:
        """Run ``programs`` (all arms at once). Each is written from rest (the joint move
        to the gate first) or is the way to rest (``[rest]``). Where each arm is, is
        judged from the joints the controller reports (``drivers/yumi/arm_place.py``):
        at rest, at its gate, on a straight leg over its table box (:meth:`_way`), or
        refused; every program's gate joints are checked at the gate and every target
        reachable (:func:`refuse_unreachable`); all before anything is sent."""
        tcp = self._controller.tcp_xyz()
        joints = self._controller.joints()
        out: dict[str, list[Waypoint]] = {}
        for arm, wps in programs.items():
            way = self._way(arm, place_of(arm, self._room(arm), tcp[arm], joints[arm]), wps)
            if way:
                out[arm] = way
        if not out:
            return
        for arm, wps in out.items():
            refuse_unreachable(arm, self._arms[arm].calibration, wps, joints[arm])
        self._controller.execute(out)

    def save_calibration(self, arm: str, data: Mapping[str, Any]) -> str:
        """Validate ``data`` as ``arm``'s calibration and replace its file atomically (a
        crash leaves the old file or the new one, never half of one). The running backend
        keeps its calibration: the new one is used from the agent's next start."""
        if arm not in self._arms:
            raise ValueError(f"unknown arm {arm!r}; this host has {list(self._arms)}")
        path = self._cal_paths.get(arm)
        if path is None:
            raise BackendError(f"arm {arm}: no calibration file configured for it")
        if not isinstance(data, Mapping):
            raise ValueError(f"arm {arm}: calibration data must be an object, got "
                             f"{type(data).__name__}")
        if "tool_z_mm" not in data:  # the frame this agent drove with: the controller's
            data = {**data, "tool_z_mm": self._arms[arm].calibration.tool_z_mm}
        if "gate_joints_deg" not in data and arm in self._measured_gate:  # read at its gate
            data = {**data, "gate_joints_deg": self._measured(arm)["gate_joints_deg"]}
        try:
            ArmCalibration.from_dict(data, arm, path)
        except BackendError as exc:
            raise ValueError(str(exc)) from None
        write_atomic(Path(path), json.dumps(dict(data), indent=2) + "\n")
        return path

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            try:
                self._camera.close()
            finally:
                self._controller.close()


def refuse_unreachable(arm: str, cal: ArmCalibration, waypoints: Sequence[Waypoint],
                       joints: Sequence[float] | None = None) -> None:
    """BackendError, before anything moves, when a waypoint is one the arm cannot reach
    with the pusher down at its arm angle (out of reach, past a joint limit:
    ``drivers/yumi/irb14000_ik.py``; a target whose solutions found here are all near a
    singularity is left to the controller, which takes the configuration itself, ConfJ
    off, and stops a line that passes one with 50026): the controller would stop the task
    half-way through the program; this names the point and the reason instead. It can
    tell only what it knows: an arm whose side cannot be told (not an IRB 14000 task, not named
    left/right), is not checked here (``testbed check`` still judges its layout).

    A joint target (``abs_j``: the driver's only one is the gate) must be within the
    joint limits and put the pusher's tip at the gate (``drivers/yumi/gate.py``). Every
    straight line must be one the model runs holding the arm angle the controller turns
    along it (``drivers/yumi/line_plan.py``: the plan the program's robtargets carry),
    planned from ``joints`` (the arm's, ABB's order, as the controller reports them; the
    program's first line is not judged without them)."""
    from drivers.yumi.layout_check import layout_of

    lay = layout_of(arm, layout_keys(cal), task=cal.pose.task if cal.pose else None)
    if lay is None:
        return
    seed = None
    for w in waypoints:
        if w.kind == "abs_j" and w.joints_deg is not None:
            if why := gate_problem(lay.tool, w.joints_deg, cal.gate_xyz, cal.table_box_mm):
                raise BackendError(f"arm {arm}: {why}; nothing was moved: {GATE_HOW}")
            seed = lay.tool.model.pose_abb(w.joints_deg).chain_deg
            continue
        if w.xyz_mm is None:
            continue
        sol = lay.tool.solve(w.xyz_mm, seed)
        if sol.pose is None and sol.kind == "singular":
            continue  # the controller picks the configuration (ConfJ off): its call
        if sol.pose is None:
            x, y, z = w.xyz_mm
            raise BackendError(
                f"arm {arm}: target ({x:.0f}, {y:.0f}, {z:.0f}) mm cannot be reached with "
                f"the pusher down (tool_z_mm {lay.tool.tool_z_mm:g}, arm angle "
                f"{lay.tool.arm_angle_deg:g} deg): {sol.reason}; nothing was moved")
        seed = sol.pose.chain_deg
    from drivers.yumi.line_plan import planned_targets

    start = None if joints is None else lay.tool.model.pose_abb(joints).chain_deg
    _, why = planned_targets(lay.tool, start, lay.rest_joints_deg, waypoints)
    if why is not None:
        raise BackendError(f"arm {arm}: the arm cannot run the program's straight lines "
                           f"holding the arm angle the controller turns along each: {why}; "
                           f"nothing was moved")


def build_yumi_backend(arms: Sequence[str], mirror: Sequence[bool],
                       crops: Mapping[str, tuple[int, int, int, int]],
                       calibrations: Mapping[str, str], camera: str | None,
                       controller_url: str | None, seed: int = 0,
                       calibrating: Collection[str] = (), *,
                       credentials_file: str | None = None,
                       motion_timeout_s: float | None = None,
                       camera_settings: Mapping[str, Any] | str | None = None,
                       zones_state_dir: str | None = None) -> YumiBackend:
    """The agent's ``--backend yumi``: its camera, its controller (real or twin).

    Paths (calibration files, a video-file camera) are host paths: ``~`` and ``$VARS``
    are expanded here, on the host. ``calibrating``: arms in calibration mode (see the
    module docstring). ``camera_settings``: the host's ``camera_settings`` (a mapping, or
    the agent's ``--camera-settings`` JSON), set on a V4L2 camera and read back
    (``drivers/cameras/capture_settings.py``). ``zones_state_dir``: the robot lock's
    folder, where the zones proof is recorded for the next agent
    (``drivers/yumi/zones_proof.py``; None: not recorded).
    """
    from drivers.cameras.camera import VideoCaptureCamera
    from drivers.yumi.controllers import make_controller

    if camera is None:
        raise BackendError("--backend yumi needs --camera (a device index, /dev path or "
                           "card name, a video file, or an http(s)/rtsp URL)")
    if controller_url is None:
        raise BackendError("--backend yumi needs --controller-url (the controller's Robot "
                           "Web Services, http(s)://HOST[:PORT])")
    if unknown := [a for a in calibrating if a not in arms]:
        raise BackendError(f"--calibrate {unknown[0]}: no such arm; this host has {list(arms)}")
    setups: list[ArmSetup] = []
    paths: dict[str, str] = {}
    for name, m in zip(arms, mirror, strict=True):
        if name not in crops:
            raise BackendError(f"arm {name}: --crop {name}=x0,y0,x1,y1 is required for yumi")
        if name not in calibrations:
            raise BackendError(f"arm {name}: --calibration {name}=FILE is required for yumi")
        paths[name] = expand_path(calibrations[name], f"arm {name}: calibration")
        cal = (provisional_calibration(paths[name], name, tool_of(
            paths[name], name, controller_url, credentials_file)) if name in calibrating
               else ArmCalibration.load(paths[name], name))
        setups.append(ArmSetup(name, crops[name], m, cal))
    if credentials_file is not None:
        credentials_file = expand_path(credentials_file, "credentials_file")
    ctrl = make_controller(controller_url, {s.name: s.calibration.pose for s in setups},
                           credentials_file=credentials_file,
                           motion_timeout_s=15.0 if motion_timeout_s is None
                           else motion_timeout_s, zones_state_dir=zones_state_dir)
    try:
        if not camera.isdigit() and not is_url(camera):
            camera = expand_path(camera, "camera")
        cam = VideoCaptureCamera(camera, settings=camera_settings)
    except Exception:
        ctrl.close()
        raise
    return YumiBackend(setups, cam, ctrl, seed=seed, calibration_paths=paths,
                       calibrating=calibrating)
