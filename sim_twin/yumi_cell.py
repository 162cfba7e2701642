"""The YuMi hardware twin: a bimanual PyBullet cell in the robot base frame, in mm.

Why it exists: the physical path (YumiBackend: camera seam, controller seam, calibration)
must be rehearsed end to end before a real YuMi is in the room. This cell stands in for
the robot and the lab: it runs waypoint programs with real contact, renders what the
overhead camera would see (lens distortion, sensor noise, an ArUco marker on each
pusher's cap), plays the lab hand that puts a cube back, and tells the truth to the
rehearsal's recorder. It knows nothing of the task (goals, success): the backend under
test does that from the picture, exactly as in the lab.

Physics as in the plain twin (sim_twin/world.py): one DIRECT client, 240 Hz, the pusher
a floating cylinder held by a fixed constraint with a force limit whose target follows
the commanded TCP path every step, so its contact with the cube is ordinary rigid-body
contact with friction. PyBullet works in metres; everything here is mm at the surface.

Motion model: every segment (move_j, move_l and rest alike) is a straight line at the
commanded speed with a trapezoidal profile (acceleration ACCEL_MM_S2) that stops at the
waypoint; zone points (``fine = False``) are accepted and also stopped at (a real zone
blends the corner and finishes a little sooner). The pusher does not collide with the
table (a TCP at z = 0 would rub on it); the cap is drawn, not simulated (see below).

Rendering: TinyRenderer draws the cubes and pusher cylinders into an ideal pinhole
picture a few pixels larger than the camera's; the table is painted in software (a flat
table renders flat, and rasterising it would cost ten times the rest); each cap (white,
with the arm's ArUco marker) is warped onto its four projected corners; the lens
distortion is then applied with one cv2.remap, so cubes, caps and markers are distorted
by exactly the model published at /lab/camera. A frame is rendered only when the world
changed; sensor noise is added per frame on top.

Over 450 lines, on purpose: one PyBullet world (two arms, the cube, the camera, the
markers) whose methods all act on it; the paths' maths is in ``yumi_arms.py`` and
``rws/``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pybullet as pb

from sim_twin.constants import CUBE_RGBA, PUSHER_RGBA, SOLVER_ITERATIONS, TABLE_RGB, TIME_STEP_S
from sim_twin.world import CubeParams
from sim_twin.yumi_geometry import (
    CAP_MM,
    CUBE_MM,
    FLOOR_Z_MM,
    MARKER_DICT,
    MARKER_IDS,
    MARKER_MM,
    NOISE_SIGMA,
    PUSHER_HEIGHT_MM,
    PUSHER_RADIUS_MM,
    REST_MM,
    TABLE_BOX_MM,
    TABLE_THICKNESS_MM,
    WORKSPACE_MM,
    CameraModel,
    arm_side,
    workspace_mm,
)

BGR = npt.NDArray[np.uint8]
M = 0.001  # mm -> m

ACCEL_MM_S2 = 2000.0
MAX_SPEED_MM_S = 1500.0
"""YuMi's top TCP speed: faster commands are refused like any bad program."""
RESET_NOISE = 0.08
"""The lab hand puts the cube within +-RESET_NOISE of the workspace side of its centre."""
_PUSHER_MASS_KG = 0.5
_PUSHER_FORCE_N = 100.0
_SETTLE_SPEED_MM_S = 5.0
_SETTLE_SPIN_RAD_S = 0.2
_SETTLE_MIN_STEPS = 8
_SETTLE_MAX_STEPS = 720
_SETTLE_CHECK_EVERY = 4
_MARGIN_PX = 8
"""Extra pixels of the ideal picture on each side (the barrel distortion pulls ~2 px in)."""
_ON_TABLE_Z_MM = 10.0
_FALLEN_Z_MM = -5.0
_CAP_WHITE, _CAP_BLACK = 215, 28
_TEX_PX_PER_MM = 2
_NOISE_BANK = 4
_LIGHT = {"lightDirection": [0.0, 0.0, 1.0], "lightAmbientCoeff": 0.1,
          "lightDiffuseCoeff": 0.9, "lightSpecularCoeff": 0.0, "shadow": 0}
"""An overhead lamp: faces turned up are lit, vertical faces dim (as under a ceiling
light), so the visible top face dominates the cube's outline in the picture."""
_KINDS = ("move_j", "move_l", "rest")


@dataclass(frozen=True, slots=True)
class Segment:
    """One straight TCP move, trapezoidal speed profile, from ``a`` to ``b`` (mm)."""

    a: tuple[float, float, float]
    b: tuple[float, float, float]
    speed: float

    @property
    def length(self) -> float:
        return math.dist(self.a, self.b)

    @property
    def duration(self) -> float:
        L, v = self.length, self.speed
        if L <= 0.0:
            return 0.0
        if v * v / ACCEL_MM_S2 <= L:
            return L / v + v / ACCEL_MM_S2
        return 2.0 * math.sqrt(L / ACCEL_MM_S2)

    def at(self, t: float) -> tuple[float, float, float]:
        """The commanded point ``t`` seconds into the segment."""
        L, v, A = self.length, self.speed, ACCEL_MM_S2
        T = self.duration
        if L <= 0.0 or t >= T:
            return self.b
        vp = min(v, math.sqrt(L * A))  # peak speed (a triangle when the move is short)
        ta = vp / A
        if t < ta:
            s = 0.5 * A * t * t
        elif t <= T - ta:
            s = 0.5 * A * ta * ta + vp * (t - ta)
        else:
            s = L - 0.5 * A * (T - t) ** 2
        f = min(max(s / L, 0.0), 1.0)
        return (self.a[0] + f * (self.b[0] - self.a[0]), self.a[1] + f * (self.b[1] - self.a[1]),
                self.a[2] + f * (self.b[2] - self.a[2]))


@dataclass(frozen=True, slots=True)
class PathSegment:
    """A move whose TCP follows given samples (``(t, xyz)``, t from the segment's start,
    increasing, the last at its end): a joint move, whose pusher goes where the arm's
    interpolated joints put it, not in a line. ``a``, ``b``, ``speed`` as :class:`Segment`."""

    a: tuple[float, float, float]
    b: tuple[float, float, float]
    speed: float
    samples: tuple[tuple[float, tuple[float, float, float]], ...]

    @property
    def length(self) -> float:
        return math.dist(self.a, self.b)

    @property
    def duration(self) -> float:
        return self.samples[-1][0]

    def at(self, t: float) -> tuple[float, float, float]:
        prev_t, prev_p = 0.0, self.a
        for ts, p in self.samples:
            if t < ts:
                f = (t - prev_t) / (ts - prev_t) if ts > prev_t else 1.0
                return (prev_p[0] + f * (p[0] - prev_p[0]), prev_p[1] + f * (p[1] - prev_p[1]),
                        prev_p[2] + f * (p[2] - prev_p[2]))
            prev_t, prev_p = ts, p
        return self.b


class Trajectory:
    """An arm's program as a chain of segments in time."""

    def __init__(self, segments: Sequence[Segment | PathSegment]) -> None:
        self.segments = list(segments)
        self.duration = sum(s.duration for s in self.segments)

    def at(self, t: float) -> tuple[float, float, float]:
        for s in self.segments:
            if t < s.duration:
                return s.at(t)
            t -= s.duration
        return self.segments[-1].b


def _number(v: Any, what: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ValueError(f"{what} must be a number, got {v!r}")
    f = float(v)
    if not math.isfinite(f):
        raise ValueError(f"{what} must be finite, got {v!r}")
    return f


def _segment(a: tuple[float, float, float], b: tuple[float, float, float], speed: float,
             path: Any, what: str) -> Segment | PathSegment:
    """A waypoint's move: a line, or with ``path`` (the samples a twin with arms gives a
    joint move: ``[(t, [x, y, z]), ...]``, t from the move's start) along them, ending at
    ``b`` at the last sample's time."""
    if path is None:
        return Segment(a, b, speed)
    try:
        samples = tuple((float(t), (float(p[0]), float(p[1]), float(p[2]))) for t, p in path)
    except (TypeError, ValueError, IndexError):
        raise ValueError(f"{what}: path must be [[t, [x, y, z]], ...]") from None
    if not samples or any(t1 <= t0 for (t0, _), (t1, _) in itertools.pairwise(samples)) or \
            samples[0][0] <= 0.0:
        raise ValueError(f"{what}: path times must increase from above 0")
    return PathSegment(a, b, speed, (*samples[:-1], (samples[-1][0], b)))


def _marker_texture(marker_id: int) -> npt.NDArray[np.uint8]:
    """The cap's top face as a grey picture, _TEX_PX_PER_MM pixels per mm, upright."""
    k = _TEX_PX_PER_MM
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, MARKER_DICT))
    side = round(MARKER_MM * k)
    marker = cv2.aruco.generateImageMarker(dictionary, marker_id, side)
    cap = np.full((round(CAP_MM * k), round(CAP_MM * k)), _CAP_WHITE, np.uint8)
    o = (cap.shape[0] - side) // 2
    cap[o:o + side, o:o + side] = np.where(marker > 127, _CAP_WHITE, _CAP_BLACK)
    return cv2.GaussianBlur(cap, (0, 0), 0.5 * k)  # ~ area sampling at 1 px per mm


_MAPS: dict[bytes, tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]] = {}


def _distortion_maps(cam: CameraModel) -> tuple[npt.NDArray[np.float32],
                                                 npt.NDArray[np.float32]]:
    """The remap tables of a camera, computed once per process (0.2 s each)."""
    key = np.concatenate([cam.K.ravel(), cam.dist, [cam.width, cam.height]]).tobytes()
    if key not in _MAPS:
        _MAPS[key] = cam.distortion_maps(_MARGIN_PX)
    return _MAPS[key]


class YumiTwinCell:
    """The bimanual cell. Not thread-safe (the server holds a lock around it)."""

    def __init__(self, seed: int, arms: Sequence[str] = ("left", "right"), *,
                 realtime: float = 0.0) -> None:
        self.arms = tuple(arms)
        self.sides = arm_side(self.arms)
        self.realtime = float(realtime)
        self.camera = CameraModel.default()
        self.version = 0
        """Incremented whenever the world changed (the renderer's cache key)."""
        self._rng = np.random.default_rng(seed)
        self._noise_rng = np.random.default_rng([seed, 1])
        self._params = {a: CubeParams.draw(self._rng) for a in self.arms}
        self.rest: dict[str, tuple[float, float, float]] = {
            a: REST_MM[self.sides[a]] for a in self.arms}
        """Where a "rest" waypoint takes each pusher (:meth:`set_rest`)."""
        self._tcp = dict(self.rest)
        self._build_world()
        cam = self.camera
        self.crops = {a: cam.crop_box(workspace_mm(self.sides[a])) for a in self.arms}
        self.mirror = {a: self.sides[a] == "right" for a in self.arms}
        self._maps = _distortion_maps(cam)
        self._view, self._proj = self._gl_matrices()
        self._tex = {a: _marker_texture(MARKER_IDS[self.sides[a]]) for a in self.arms}
        self._clean: tuple[int, BGR] | None = None
        self._visible: dict[str, bool] = {}
        m = _MARGIN_PX
        self._table_img = np.empty((cam.height + 2 * m, cam.width + 2 * m, 3), np.uint8)
        self._table_img[:] = TABLE_RGB[::-1]
        self._noise = self._noise_bank()
        for a in self.arms:
            self.lab_reset(a)

    # --- world ------------------------------------------------------------------------
    def _build_world(self) -> None:
        self.client = c = pb.connect(pb.DIRECT)
        pb.resetSimulation(physicsClientId=c)
        pb.setGravity(0.0, 0.0, -9.81, physicsClientId=c)
        pb.setPhysicsEngineParameter(fixedTimeStep=TIME_STEP_S,
                                     numSolverIterations=SOLVER_ITERATIONS,
                                     deterministicOverlappingPairs=1, physicsClientId=c)
        x0, y0, x1, y1 = TABLE_BOX_MM
        half = [(x1 - x0) / 2 * M, (y1 - y0) / 2 * M, TABLE_THICKNESS_MM / 2 * M]
        table_col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=c)
        self.table = pb.createMultiBody(0.0, table_col, -1, basePosition=[
            (x0 + x1) / 2 * M, (y0 + y1) / 2 * M, -half[2]], physicsClientId=c)
        pb.changeDynamics(self.table, -1, lateralFriction=1.0, physicsClientId=c)
        pb.changeVisualShape(self.table, -1, rgbaColor=[0, 0, 0, 0], physicsClientId=c)
        plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=c)
        self.floor = pb.createMultiBody(0.0, plane, -1, basePosition=[0, 0, FLOOR_Z_MM * M],
                                        physicsClientId=c)
        pb.changeVisualShape(self.floor, -1, rgbaColor=[0, 0, 0, 0], physicsClientId=c)

        h = CUBE_MM / 2 * M
        cube_col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[h] * 3, physicsClientId=c)
        cube_vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[h] * 3, rgbaColor=CUBE_RGBA,
                                        physicsClientId=c)
        r, ph = PUSHER_RADIUS_MM * M, PUSHER_HEIGHT_MM * M
        pusher_col = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=r, height=ph,
                                             physicsClientId=c)
        pusher_vis = pb.createVisualShape(pb.GEOM_CYLINDER, radius=r, length=ph,
                                          rgbaColor=PUSHER_RGBA, physicsClientId=c)
        self.cubes: dict[str, int] = {}
        self.pushers: dict[str, int] = {}
        self._cid: dict[str, int] = {}
        for a in self.arms:
            prm = self._params[a]
            wx0, wy0, wx1, wy1 = workspace_mm(self.sides[a])
            cube = pb.createMultiBody(prm.mass_kg, cube_col, cube_vis, basePosition=[
                (wx0 + wx1) / 2 * M, (wy0 + wy1) / 2 * M, h], physicsClientId=c)
            pb.changeDynamics(cube, -1, lateralFriction=prm.friction, restitution=0.0,
                              physicsClientId=c)
            body = self._body_pos(self._tcp[a])
            pusher = pb.createMultiBody(_PUSHER_MASS_KG, pusher_col, pusher_vis,
                                        basePosition=body, physicsClientId=c)
            # Bullet multiplies the two bodies' coefficients: make the pair's be the draw.
            pb.changeDynamics(pusher, -1, lateralFriction=prm.pusher_friction / prm.friction,
                              restitution=0.0, physicsClientId=c)
            pb.setCollisionFilterPair(pusher, self.table, -1, -1, 0, physicsClientId=c)
            cid = pb.createConstraint(pusher, -1, -1, -1, pb.JOINT_FIXED, [0, 0, 0], [0, 0, 0],
                                      body, physicsClientId=c)
            pb.changeConstraint(cid, body, maxForce=_PUSHER_FORCE_N, physicsClientId=c)
            self.cubes[a], self.pushers[a], self._cid[a] = cube, pusher, cid

    @staticmethod
    def _body_pos(tcp_mm: Sequence[float]) -> list[float]:
        """The pusher body's centre (m) for a TCP (its bottom centre, mm)."""
        return [tcp_mm[0] * M, tcp_mm[1] * M, (tcp_mm[2] + PUSHER_HEIGHT_MM / 2) * M]

    def hold(self, arm: str, xyz_mm: Sequence[float]) -> None:
        """A motion stopped mid-way (a controller's stop): the arm's commanded TCP is
        where it stopped, so its next program starts from there (the pusher's constraint
        already holds it there)."""
        if arm not in self._tcp:
            raise ValueError(f"unknown arm {arm!r}; the cell has {sorted(self._tcp)}")
        x, y, z = (float(v) for v in xyz_mm)
        self._tcp[arm] = (x, y, z)

    def set_rest(self, arm: str, xyz_mm: Sequence[float]) -> None:
        """The arm's rest point: where the twin's arms hold the pusher at their rest
        joints. An arm still at its old rest is put at the new one at once (the twin has
        just started: nothing has moved yet)."""
        new = (float(xyz_mm[0]), float(xyz_mm[1]), float(xyz_mm[2]))
        if math.dist(self._tcp[arm], self.rest[arm]) < 1e-6:
            self._tcp[arm] = new
            body = self._body_pos(new)
            pb.resetBasePositionAndOrientation(self.pushers[arm], body, [0, 0, 0, 1],
                                               physicsClientId=self.client)
            pb.changeConstraint(self._cid[arm], body, maxForce=_PUSHER_FORCE_N,
                                physicsClientId=self.client)
        self.rest[arm] = new
        self.version += 1

    def halt(self, points: Mapping[str, Sequence[float]]) -> None:
        """A motion stopped at a given point (a world zone's face, which the last physics
        step may have passed by a fraction of a millimetre): each arm's pusher is pulled
        back to its point, which is also where its next program starts, and the world
        settles."""
        for arm, p in points.items():
            self.hold(arm, p)
            pb.changeConstraint(self._cid[arm], self._body_pos(self._tcp[arm]),
                                maxForce=_PUSHER_FORCE_N, physicsClientId=self.client)
        self._settle()
        self.version += 1

    def tcp_xyz(self) -> dict[str, tuple[float, float, float]]:
        """Each arm's actual TCP (the pusher's bottom centre), mm."""
        out = {}
        for a in self.arms:
            p, _ = pb.getBasePositionAndOrientation(self.pushers[a], physicsClientId=self.client)
            out[a] = (round(p[0] / M, 2), round(p[1] / M, 2),
                      round(p[2] / M - PUSHER_HEIGHT_MM / 2, 2))
        return out

    # --- programs ---------------------------------------------------------------------
    def plan(self, programs: Mapping[str, Sequence[Mapping[str, Any]]]) -> dict[str, Trajectory]:
        """Validate every arm's waypoint list and chain it from the arm's commanded TCP;
        raises ValueError (naming arm and waypoint) before anything moves."""
        if not isinstance(programs, Mapping):
            raise ValueError("programs must be an object {arm: [waypoint, ...]}")
        plans: dict[str, Trajectory] = {}
        for arm, program in programs.items():
            if arm not in self.arms:
                raise ValueError(f"unknown arm {arm!r} (this cell has {list(self.arms)})")
            if not isinstance(program, Sequence) or isinstance(program, str):
                raise ValueError(f"arm {arm}: the program must be a list of waypoints")
            here, segs = self._tcp[arm], []
            for i, wp in enumerate(program):
                what = f"arm {arm} waypoint {i}"
                if not isinstance(wp, Mapping):
                    raise ValueError(f"{what}: must be an object")
                kind = wp.get("kind")
                if kind not in _KINDS:
                    raise ValueError(f"{what}: kind must be one of {list(_KINDS)}, got {kind!r}")
                speed = _number(wp.get("speed_mm_s"), f"{what}: speed_mm_s")
                if not 0.0 < speed <= MAX_SPEED_MM_S:
                    raise ValueError(f"{what}: speed_mm_s must be in (0, {MAX_SPEED_MM_S:g}], "
                                     f"got {speed:g}")
                if kind == "rest":
                    target = self.rest[arm]
                else:
                    xyz = wp.get("xyz_mm")
                    if not isinstance(xyz, Sequence) or isinstance(xyz, str) or len(xyz) != 3:
                        raise ValueError(f"{what}: xyz_mm must be [x, y, z] (mm)")
                    target = tuple(_number(v, f"{what}: xyz_mm") for v in xyz)  # type: ignore[assignment]
                    if target[2] < 0.0 and wp.get("joints_deg") is None:
                        raise ValueError(f"{what}: z = {target[2]:g} mm is below the table")
                segs.append(_segment(here, target, speed, wp.get("path"), what))
                here = target
            plans[arm] = Trajectory(segs)
        return plans

    def execute(self, programs: Mapping[str, Sequence[Mapping[str, Any]]], *,
                on_frame: Callable[[], None] | None = None, frame_every_s: float = 0.0
                ) -> float:
        """Run every arm's program at once (MultiMove), then let the cubes settle.
        Returns the simulated duration in seconds. ``on_frame`` is called every
        ``frame_every_s`` simulated seconds during the motion (a live camera)."""
        plans = {a: t for a, t in self.plan(programs).items() if t.segments}
        c, dt = self.client, TIME_STEP_S
        steps = math.ceil(max((t.duration for t in plans.values()), default=0.0) / dt)
        pace = self._pacer()
        next_frame = frame_every_s
        for i in range(1, steps + 1):
            for a, traj in plans.items():
                pb.changeConstraint(self._cid[a], self._body_pos(traj.at(i * dt)),
                                    maxForce=_PUSHER_FORCE_N, physicsClientId=c)
            pb.stepSimulation(physicsClientId=c)
            pace(i * dt)
            if on_frame is not None and frame_every_s > 0 and i * dt >= next_frame:
                self.version += 1
                on_frame()
                next_frame += frame_every_s
        for a, traj in plans.items():
            self._tcp[a] = traj.segments[-1].b
        n = self._settle()
        pace((steps + n) * dt)
        if plans:
            self.version += 1
        return (steps + n) * dt

    def _pacer(self) -> Callable[[float], None]:
        import time

        realtime = self.realtime  # once: the pace of this move (a change applies to the next)
        if realtime <= 0:
            return lambda sim_s: None
        t0 = time.monotonic()

        def pace(sim_s: float) -> None:
            ahead = t0 + sim_s / realtime - time.monotonic()
            if ahead > 0.002:
                time.sleep(ahead)
        return pace

    def _settle(self) -> int:
        """Step until every cube and every pusher is at rest (a fixed rule:
        deterministic; a pusher that trailed its constraint on a fast joint move has
        arrived, as a fine point waits for the arm to be in position). Returns steps."""
        c = self.client
        for i in range(1, _SETTLE_MAX_STEPS + 1):
            pb.stepSimulation(physicsClientId=c)
            if i >= _SETTLE_MIN_STEPS and i % _SETTLE_CHECK_EVERY == 0 and all(
                    self._still(self.cubes[a]) and self._still(self.pushers[a])
                    for a in self.arms):
                return i
        return _SETTLE_MAX_STEPS

    def _still(self, body: int) -> bool:
        lin, ang = pb.getBaseVelocity(body, physicsClientId=self.client)
        return (math.sqrt(sum(v * v for v in lin)) / M < _SETTLE_SPEED_MM_S
                and math.sqrt(sum(w * w for w in ang)) < _SETTLE_SPIN_RAD_S)

    # --- the lab ------------------------------------------------------------------------
    def lab_reset(self, arm: str) -> None:
        """The lab hand: the arm's cube near its workspace centre, any yaw, settled.
        Never on top of a pusher that is down in the workspace (the hand avoids it)."""
        if arm not in self.arms:
            raise ValueError(f"unknown arm {arm!r} (this cell has {list(self.arms)})")
        x0, y0, x1, y1 = workspace_mm(self.sides[arm])
        centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        tcps = self.tcp_xyz()
        for _ in range(100):
            xy = centre + self._rng.uniform(-RESET_NOISE, RESET_NOISE, 2) * WORKSPACE_MM
            yaw = float(self._rng.uniform(0.0, 2.0 * math.pi))
            clear = CUBE_MM * math.sqrt(0.5) + PUSHER_RADIUS_MM + 5.0
            if all(p[2] > CUBE_MM + 5.0 or math.dist(p[:2], xy) > clear for p in tcps.values()):
                break
        self.place_cube(arm, (float(xy[0]), float(xy[1])), yaw)

    def place_cube(self, arm: str, xy_mm: Sequence[float], yaw: float) -> None:
        """Put a cube flat on the table at (x, y) mm, yaw rad, and let it settle."""
        c = self.client
        pb.resetBasePositionAndOrientation(
            self.cubes[arm], [xy_mm[0] * M, xy_mm[1] * M, (CUBE_MM / 2 + 0.05) * M],
            pb.getQuaternionFromEuler([0.0, 0.0, yaw]), physicsClientId=c)
        pb.resetBaseVelocity(self.cubes[arm], [0, 0, 0], [0, 0, 0], physicsClientId=c)
        self._settle()
        self.version += 1

    def cube_pose(self, arm: str) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Centre (mm) and rotation matrix of an arm's cube."""
        p, q = pb.getBasePositionAndOrientation(self.cubes[arm], physicsClientId=self.client)
        rot = np.asarray(pb.getMatrixFromQuaternion(q)).reshape(3, 3)
        return np.asarray(p) / M, rot

    def truth(self) -> dict[str, dict[str, Any]]:
        """Per arm: cube centre (mm), on the table, the projected centre of its top face
        (distorted pixels, OpenCV convention), its yaw in image axes (mod a quarter turn)."""
        out: dict[str, dict[str, Any]] = {}
        for a in self.arms:
            centre, rot = self.cube_pose(a)
            up = int(np.argmax(np.abs(rot[2])))  # the body axis closest to vertical
            top = centre + rot[:, up] * np.sign(rot[2, up]) * CUBE_MM / 2
            side = (up + 1) % 3  # a horizontal-ish body axis: its heading is the yaw
            u, v = self.project(top)
            out[a] = {"cube_mm": [round(float(x), 3) for x in centre],
                      "on_table": bool(centre[2] > _ON_TABLE_Z_MM),
                      "cube_px": [round(u, 3), round(v, 3)],
                      "yaw_px": round(self.camera.image_yaw(
                          math.atan2(rot[1, side], rot[0, side])), 5)}
        return out

    def project(self, xyz_mm: Sequence[float]) -> tuple[float, float]:
        """Distorted pixel (u, v) of a world point (mm) through the true camera."""
        u, v = self.camera.project(xyz_mm)[0]
        return (float(u), float(v))

    @property
    def camera_model(self) -> dict[str, Any]:
        """Everything /lab/camera publishes: the true camera and the cell's layout."""
        d = self.camera.as_json()
        d.update({
            "crops": {a: list(self.crops[a]) for a in self.arms},
            "mirror": dict(self.mirror),
            "workspaces_mm": {a: list(workspace_mm(self.sides[a])) for a in self.arms},
            "rest_mm": {a: list(self.rest[a]) for a in self.arms},
            "table_mm": list(TABLE_BOX_MM),
            "marker": {"dict": MARKER_DICT,
                       "ids": {a: MARKER_IDS[self.sides[a]] for a in self.arms},
                       "plane_z_above_tcp_mm": PUSHER_HEIGHT_MM,
                       "side_mm": MARKER_MM, "cap_mm": CAP_MM},
            "pixel_convention": "opencv: the centre of pixel (i, j) is at (i, j)",
            "noise_sigma": NOISE_SIGMA,
        })
        return d

    # --- the camera ----------------------------------------------------------------------
    def _gl_matrices(self) -> tuple[list[float], list[float]]:
        """PyBullet view/projection matrices of the ideal pinhole K, on a picture
        _MARGIN_PX larger on every side (column-major, OpenGL conventions)."""
        cam, m = self.camera, _MARGIN_PX
        R, t = cam.R, cam.t
        eye = -R.T @ t
        fwd = R[2]  # camera z, world frame
        up = -R[1]  # image up
        view = pb.computeViewMatrix((eye * M).tolist(), ((eye + fwd * 100.0) * M).tolist(),
                                    up.tolist())
        W, H = cam.width + 2 * m, cam.height + 2 * m
        fx, fy = cam.K[0, 0], cam.K[1, 1]
        cx, cy = cam.K[0, 2] + m + _TR_SHIFT[0], cam.K[1, 2] + m + _TR_SHIFT[1]
        n, f = 0.5, 2.5
        P = np.zeros((4, 4))
        P[0, 0], P[0, 2] = 2 * fx / W, 1 - 2 * (cx + 0.5) / W
        P[1, 1], P[1, 2] = 2 * fy / H, 2 * (cy + 0.5) / H - 1
        P[2, 2], P[2, 3] = -(f + n) / (f - n), -2 * f * n / (f - n)
        P[3, 2] = -1.0
        return list(view), P.T.ravel().tolist()

    def _render_clean(self) -> BGR:
        if self._clean is not None and self._clean[0] == self.version:
            return self._clean[1]
        cam, m = self.camera, _MARGIN_PX
        W, H = cam.width + 2 * m, cam.height + 2 * m
        for a in self.arms:  # a cube on the floor is hidden by the table above it
            self._show_cube(a, self.cube_pose(a)[0][2] >= _FALLEN_Z_MM)
        out = pb.getCameraImage(W, H, self._view, self._proj, renderer=pb.ER_TINY_RENDERER,
                                flags=pb.ER_NO_SEGMENTATION_MASK, physicsClientId=self.client,
                                **_LIGHT)
        rgba = np.asarray(out[2], dtype=np.uint8).reshape(H, W, 4)
        depth = np.asarray(out[3], dtype=np.float32).reshape(H, W)
        img = cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGR)
        # Nothing drawn (the far plane) is the table: the table and the floor are invisible
        # bodies, and painting costs nothing next to rasterising them.
        cv2.copyTo(self._table_img, (depth >= 1.0).view(np.uint8), img)
        for a, tcp in self.tcp_xyz().items():
            self._draw_cap(img, a, tcp)
        img = cv2.remap(img, *self._maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        self._clean = (self.version, img)
        return img

    def _show_cube(self, arm: str, visible: bool) -> None:
        if self._visible.get(arm) != visible:
            rgba = list(CUBE_RGBA) if visible else [0.0, 0.0, 0.0, 0.0]
            pb.changeVisualShape(self.cubes[arm], -1, rgbaColor=rgba, physicsClientId=self.client)
            self._visible[arm] = visible

    def _draw_cap(self, img: BGR, arm: str, tcp: Sequence[float]) -> None:
        """Warp the cap's top face (the marker) onto its projected corners, in the ideal
        picture, blending its anti-aliased edge."""
        h, z = CAP_MM / 2, tcp[2] + PUSHER_HEIGHT_MM
        x, y = tcp[0], tcp[1]
        # Texture top-left, top-right, bottom-right, bottom-left: far-left, far-right,
        # near-right, near-left as seen from the robot (upright in the picture).
        world = [(x + h, y + h, z), (x + h, y - h, z), (x - h, y - h, z), (x - h, y + h, z)]
        dst = self.camera.project_ideal(world) + _MARGIN_PX
        H, W = img.shape[:2]
        lo, hi = np.floor(dst.min(0)).astype(int) - 1, np.ceil(dst.max(0)).astype(int) + 2
        x0, y0 = max(lo[0], 0), max(lo[1], 0)
        x1, y1 = min(hi[0], W), min(hi[1], H)
        if x0 >= x1 or y0 >= y1:
            return  # out of view
        tex = self._tex[arm]
        s = tex.shape[0]
        src = np.array([[-0.5, -0.5], [s - 0.5, -0.5], [s - 0.5, s - 0.5], [-0.5, s - 0.5]],
                       np.float32)
        Hm = cv2.getPerspectiveTransform(src, (dst - [x0, y0]).astype(np.float32))
        size = (x1 - x0, y1 - y0)
        face = cv2.warpPerspective(tex.astype(np.float32), Hm, size, flags=cv2.INTER_LINEAR,
                                   borderMode=cv2.BORDER_REPLICATE)
        pad = np.zeros((s + 2, s + 2), np.float32)
        pad[1:-1, 1:-1] = 1.0
        Hp = Hm @ np.array([[1, 0, -1], [0, 1, -1], [0, 0, 1]], np.float64)
        alpha = cv2.warpPerspective(pad, Hp, size, flags=cv2.INTER_LINEAR)[..., None]
        roi = img[y0:y1, x0:x1].astype(np.float32)
        img[y0:y1, x0:x1] = np.clip(roi * (1 - alpha) + face[..., None] * alpha + 0.5, 0,
                                    255).astype(np.uint8)

    def render(self, noise: bool = True) -> BGR:
        """The camera's picture of the current world: (480, 640, 3) uint8 BGR."""
        clean = self._render_clean()
        if not noise:
            return clean.copy()
        return self.add_noise(clean)

    def _noise_bank(self) -> list[tuple[BGR, BGR]]:
        """A few frames of Gaussian noise as (positive, negative) uint8 parts, so that a
        noisy frame is two saturating cv2 adds (drawing 1M normals costs ~30 ms)."""
        shape = (self.camera.height, self.camera.width, 3)
        bank = []
        for _ in range(_NOISE_BANK):
            n = np.rint(self._noise_rng.standard_normal(shape, dtype=np.float32) * NOISE_SIGMA)
            bank.append((np.clip(n, 0, 255).astype(np.uint8), np.clip(-n, 0, 255).astype(np.uint8)))
        return bank

    def add_noise(self, clean: BGR) -> BGR:
        """Sensor noise on a clean picture: a bank frame, rolled by a random number of
        rows and columns, so consecutive frames differ (may run outside the lock)."""
        pos, neg = self._noise[int(self._noise_rng.integers(len(self._noise)))]
        dy, dx = (int(v) for v in self._noise_rng.integers(0, 64, 2))
        if dy or dx:
            pos, neg = np.roll(pos, (dy, dx), (0, 1)), np.roll(neg, (dy, dx), (0, 1))
        return cv2.subtract(cv2.add(clean, pos), neg)

    # --- lifetime -------------------------------------------------------------------------
    def close(self) -> None:
        if self.client >= 0:
            pb.disconnect(physicsClientId=self.client)
            self.client = -1

    def __enter__(self) -> YumiTwinCell:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


_TR_SHIFT = (-0.5, 0.5)
"""TinyRenderer's sampling offset against the ideal pinhole, in pixels (measured)."""
