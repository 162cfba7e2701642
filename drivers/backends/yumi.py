"""The ABB YuMi (IRB 14000) host: two arms, one overhead camera, one controller.

Why it looks like this: the policy acts in the arm's canonical 64x64 image frame, the
robot moves in millimetres in its base frame. A per-arm calibration file holds the
image-to-table homography that joins the two, plus the safety envelope (a table box
every waypoint is clipped into, a speed cap, push and travel heights) and the rest pose
out of the camera's view. The task bookkeeping the twin does in simulation (goal drawn
into the image, success, violation, soft reset after success or 50 pushes) is done
here from the picture, with ``testbed.perception`` (imported lazily: the agent on a
robot host needs numpy and cv2 only).

One push, per arm (all arms' programs run at once, MultiMove)::

    canonical face k, cube pose (perception) --start/end in canonical units-->
    crop pixel --(mirror, crop box)--> camera pixel --homography--> table mm
    --clip to the table box--> waypoints: above start, down, stroke, up, rest pose

A picture is only taken with every TCP outside the camera's view; if an arm is in view
(before or after the shot) it is sent to rest and the picture is taken again.
"""

from __future__ import annotations

import importlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from drivers.backends.base import ArmOutcome, ArmView, HostBackend
from drivers.backends.camera import Camera
from drivers.backends.yumi_controller import ArmPose, Waypoint, YumiControllerClient
from drivers.errors import BackendError
from testbed.types import (
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


@dataclass(frozen=True, slots=True)
class ArmCalibration:
    """One arm's calibration file (JSON), validated on load."""

    homography: npt.NDArray[np.float64]
    """3x3: camera pixel (u, v, 1) -> table point in the robot base frame (x, y, w), mm."""
    table_box_mm: tuple[float, float, float, float]
    """(x_min, y_min, x_max, y_max): every waypoint's (x, y) is clipped into it."""
    z_push_mm: float = 10.0
    z_travel_mm: float = 80.0
    max_speed_mm_s: float = 150.0
    push_speed_mm_s: float = 50.0
    start_offset: float = 8.0 / 64.0
    """Push start, canonical units outside the chosen face (as the twin)."""
    stroke: float = 0.15
    """Push stroke length, canonical units past the start (cube moves ~ stroke - offset)."""
    pose: ArmPose | None = None

    @classmethod
    def load(cls, path: str | Path, arm: str) -> ArmCalibration:
        p = Path(path)
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise BackendError(f"arm {arm}: cannot read calibration {p}: {exc}") from None
        return cls.from_dict(d, arm, str(p))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], arm: str, source: str = "calibration"
                  ) -> ArmCalibration:
        def bad(msg: str) -> BackendError:
            return BackendError(f"arm {arm}: {source}: {msg}")

        try:
            h = np.asarray(d["homography"], dtype=np.float64)
            box = tuple(float(v) for v in d["table_box_mm"])
        except (KeyError, TypeError, ValueError) as exc:
            raise bad(f"needs 'homography' (3x3) and 'table_box_mm' (4 numbers): {exc}") from None
        if h.shape != (3, 3) or not np.all(np.isfinite(h)) or abs(np.linalg.det(h)) < 1e-12:
            raise bad("'homography' must be an invertible 3x3 matrix")
        if len(box) != 4 or box[0] >= box[2] or box[1] >= box[3]:
            raise bad("'table_box_mm' must be (x_min, y_min, x_max, y_max)")
        known = {"homography", "table_box_mm", "z_push_mm", "z_travel_mm", "max_speed_mm_s",
                 "push_speed_mm_s", "start_offset", "stroke", "task", "mechunit",
                 "rest_joints_deg", "tool_quat_wxyz", "robconf", "arm_angle_deg", "tool_z_mm"}
        if extra := set(d) - known:
            raise bad(f"unknown key(s) {sorted(extra)}")
        nums = {k: float(d[k]) for k in ("z_push_mm", "z_travel_mm", "max_speed_mm_s",
                                         "push_speed_mm_s", "start_offset", "stroke") if k in d}
        cal = cls(h, box, **nums)  # type: ignore[arg-type]
        if not 0 < cal.push_speed_mm_s <= cal.max_speed_mm_s <= 1000:
            raise bad("need 0 < push_speed_mm_s <= max_speed_mm_s <= 1000")
        if cal.z_push_mm >= cal.z_travel_mm:
            raise bad("z_push_mm must be below z_travel_mm")
        pose = None
        if "rest_joints_deg" in d:
            joints = tuple(float(v) for v in d["rest_joints_deg"])
            if len(joints) != 7:
                raise bad("'rest_joints_deg' needs 7 angles (axis 7 last)")
            side = "L" if arm.startswith("l") else "R"
            pose = ArmPose(task=str(d.get("task", f"T_ROB_{side}")),
                           mechunit=str(d.get("mechunit", f"ROB_{side}")),
                           rest_joints_deg=joints,
                           tool_quat_wxyz=tuple(d.get("tool_quat_wxyz", (0, 0, 1, 0))),
                           robconf=tuple(d.get("robconf", (0, 0, 0, 4))),
                           arm_angle_deg=float(d.get("arm_angle_deg", 0.0)),
                           tool_z_mm=float(d.get("tool_z_mm", 0.0)))
        return cls(h, box, **nums, pose=pose)  # type: ignore[arg-type]

    def pixel_to_table(self, u: float, v: float) -> tuple[float, float]:
        x, y, w = self.homography @ np.array([u, v, 1.0])
        return (float(x / w), float(y / w))

    def table_to_pixel(self, x: float, y: float) -> tuple[float, float]:
        u, v, w = np.linalg.solve(self.homography, np.array([x, y, 1.0]))
        return (float(u / w), float(v / w))


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
        return (x0 + cx * (x1 - x0), y0 + c[1] * (y1 - y0))

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
        x, y = arm.canonical_to_table(p)
        return (min(max(x, bx0), bx1), min(max(y, by0), by1), z)

    vmax = cal.max_speed_mm_s
    vpush = min(cal.push_speed_mm_s, vmax)
    return [
        Waypoint("move_j", table(start, cal.z_travel_mm), vmax, fine=False),
        Waypoint("move_l", table(start, cal.z_push_mm), min(vmax, 2 * vpush)),
        Waypoint("move_l", table(end, cal.z_push_mm), vpush),
        Waypoint("move_l", table(end, cal.z_travel_mm), min(vmax, 2 * vpush), fine=False),
        Waypoint("rest", None, vmax),
    ]


class YumiBackend(HostBackend):
    """Two YuMi arms under one camera; the controller client is injected."""

    kind = "yumi"

    def __init__(self, arms: Sequence[ArmSetup], camera: Camera,
                 controller: YumiControllerClient, *, seed: int = 0,
                 perception: Any = None, retakes: int = 3) -> None:
        if not arms:
            raise BackendError("a YuMi host needs at least one arm")
        self._arms = {a.name: a for a in arms}
        self._camera = camera
        self._controller = controller
        self._perception = perception
        self._retakes = retakes
        self._rng = np.random.default_rng(seed)
        self._goal: dict[str, tuple[float, float] | None] = dict.fromkeys(self._arms, None)
        self._violating: dict[str, bool | None] = dict.fromkeys(self._arms, None)
        self._pushes = dict.fromkeys(self._arms, 0)
        self._pose: dict[str, Any] = dict.fromkeys(self._arms, None)
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
            self._perception = importlib.import_module("testbed.perception")
        return self._perception

    # -- pictures --------------------------------------------------------------------
    def _arms_in_view(self) -> list[str]:
        w, h = self._camera.size
        tcp = self._controller.tcp_xyz()
        out = []
        for name, arm in self._arms.items():
            u, v = arm.calibration.table_to_pixel(*tcp[name][:2])
            if -0.02 * w <= u <= 1.02 * w and -0.02 * h <= v <= 1.02 * h:
                out.append(name)
        return out

    def _picture(self) -> npt.NDArray[np.uint8]:
        for _ in range(self._retakes + 1):
            if in_view := self._arms_in_view():
                self._controller.execute({a: [Waypoint("rest", None, self._arms[
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
        if any(self._pose[a] is None and self._violating[a] is None for a in faces):
            self.observe()
        moving = {a: f for a, f in faces.items()
                  if not self._violating[a] and self._pose[a] is not None}
        programs: dict[str, list[Waypoint]] = {}
        for name, arm in self._arms.items():
            if name in moving:
                pose = self._pose[name]
                programs[name] = plan_push(arm, pose.centre, float(pose.yaw), moving[name])
            else:
                programs[name] = [Waypoint("rest", None, arm.calibration.max_speed_mm_s)]
        if moving:
            self._controller.execute(programs)
            self._look()
        out: dict[str, ArmOutcome] = {}
        for arm in faces:
            if arm not in moving:  # refused: violating (or no cube seen)
                out[arm] = ArmOutcome(False, False)
                continue
            if self._out(arm):
                self._violating[arm] = True
                out[arm] = ArmOutcome(False, True)
                continue
            goal = self._goal[arm]
            success = goal is not None and bool(self.perception.is_success(self._pose[arm], goal))
            self._pushes[arm] += 1
            if success or self._pushes[arm] >= MAX_PUSHES_PER_GOAL:
                self._new_goal(arm)  # soft reset: no human needed
            out[arm] = ArmOutcome(success, False)
        return out

    def reset(self, arms: Sequence[str]) -> dict[str, bool]:
        arms = self.check_arms(arms)
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
        self._controller.execute({name: [Waypoint("rest", None, a.calibration.max_speed_mm_s)]
                                  for name, a in self._arms.items()})

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            try:
                self._camera.close()
            finally:
                self._controller.close()


def build_yumi_backend(arms: Sequence[str], mirror: Sequence[bool],
                       crops: Mapping[str, tuple[int, int, int, int]],
                       calibrations: Mapping[str, str], camera: str | None,
                       controller_url: str | None, seed: int = 0) -> YumiBackend:
    """The agent's ``--backend yumi``: real camera, real controller."""
    from drivers.backends.camera import VideoCaptureCamera
    from drivers.backends.yumi_controller import RwsYumiController

    if camera is None:
        raise BackendError("--backend yumi needs --camera (device index or video file)")
    if controller_url is None:
        raise BackendError("--backend yumi needs --controller-url (the controller's RWS URL)")
    setups: list[ArmSetup] = []
    for name, m in zip(arms, mirror, strict=True):
        if name not in crops:
            raise BackendError(f"arm {name}: --crop {name}=x0,y0,x1,y1 is required for yumi")
        if name not in calibrations:
            raise BackendError(f"arm {name}: --calibration {name}=FILE is required for yumi")
        cal = ArmCalibration.load(calibrations[name], name)
        if cal.pose is None:
            raise BackendError(f"arm {name}: calibration {calibrations[name]} has no "
                               f"'rest_joints_deg' (7 angles)")
        setups.append(ArmSetup(name, crops[name], m, cal))
    cam = VideoCaptureCamera(camera)
    try:
        poses = {s.name: s.calibration.pose for s in setups}
        ctrl = RwsYumiController(controller_url, poses)  # type: ignore[arg-type]
    except Exception:
        cam.close()
        raise
    return YumiBackend(setups, cam, ctrl, seed=seed)
