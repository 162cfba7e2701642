"""The PyBullet world of one cell: table, one cube and one pusher per arm, and the stroke.

Why a module of its own: everything that touches PyBullet's physics lives here, so the
cell above it is plain task logic. One world per cell, in its own DIRECT client, built
fresh from the seed with a fixed time step and no wall clock: the same calls give the
same floats (the twin's determinism rests on this).

The pusher is a floating cylinder held by a fixed constraint whose target is moved
every step (a position-controlled finger with a force limit): its contact with the cube
is ordinary rigid-body contact with friction, so an off-centre push turns the cube as
on the real table. Between pushes the pushers rest out of the camera's view.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import pybullet as pb

from sim_twin.constants import (
    CONTACT_GAP_M,
    CUBE_FRICTION,
    CUBE_M,
    CUBE_MASS_KG,
    CUBE_RGBA,
    PUSH_BIAS,
    PUSH_JITTER,
    PUSH_START_OFFSET,
    PUSHER_CLEARANCE_M,
    PUSHER_FRICTION,
    PUSHER_HEIGHT_M,
    PUSHER_RADIUS_M,
    PUSHER_RGBA,
    SETTLE_MAX_STEPS,
    SETTLE_MIN_STEPS,
    SETTLE_SPEED_M_S,
    SOLVER_ITERATIONS,
    STROKE_STEPS,
    TABLE_RGB,
    TIME_STEP_S,
    WORKSPACE_M,
)

_PUSHER_Z = PUSHER_CLEARANCE_M + PUSHER_HEIGHT_M / 2
_PUSHER_MASS_KG = 0.5
_PUSHER_FORCE_N = 100.0
_REST_Y_M = 0.6  # far outside the camera's view (it sees |y| <= 0.16 m)
_SETTLE_CHECK_EVERY = 4


@dataclass(frozen=True, slots=True)
class CubeParams:
    """One cube's draw from the per-seed ranges (constants.py)."""

    mass_kg: float
    friction: float
    pusher_friction: float
    push_bias: float
    push_jitter: float

    @classmethod
    def draw(cls, rng: np.random.Generator) -> CubeParams:
        def u(r: tuple[float, float]) -> float:
            return float(rng.uniform(*r))

        return cls(u(CUBE_MASS_KG), u(CUBE_FRICTION), u(PUSHER_FRICTION), u(PUSH_BIAS),
                   u(PUSH_JITTER))


@dataclass(frozen=True, slots=True)
class Stroke:
    """One pusher's straight push in world (x, y), pusher-axis positions: the primitive
    begins at ``origin`` (PUSH_START_OFFSET of the workspace outside the face), and is
    integrated from ``start`` (CONTACT_GAP_M before the face) to ``end`` (the cube's
    centre, shifted sideways like the whole line)."""

    arm: int
    origin: tuple[float, float]
    start: tuple[float, float]
    end: tuple[float, float]


class TwinWorld:
    """A DIRECT PyBullet client with the cell's bodies. Not thread-safe."""

    def __init__(self, centres: Sequence[tuple[float, float]],
                 params: Sequence[CubeParams]) -> None:
        self.client = pb.connect(pb.DIRECT)
        c = self.client
        pb.resetSimulation(physicsClientId=c)
        pb.setGravity(0.0, 0.0, -9.81, physicsClientId=c)
        pb.setPhysicsEngineParameter(fixedTimeStep=TIME_STEP_S,
                                     numSolverIterations=SOLVER_ITERATIONS,
                                     deterministicOverlappingPairs=1, physicsClientId=c)
        # An infinite plane for contact (a cube never falls off) and no table mesh to
        # render: a flat, evenly lit table renders as one colour, so the picture's empty
        # pixels are painted with it in software -- rasterising a table that fills the
        # view would cost TinyRenderer ten times the rest of the picture.
        plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=c)
        self.table = pb.createMultiBody(0.0, plane, -1, physicsClientId=c)
        pb.changeDynamics(self.table, -1, lateralFriction=1.0, physicsClientId=c)
        # Without a visual shape PyBullet draws the collision plane; transparent = skipped.
        pb.changeVisualShape(self.table, -1, rgbaColor=[0.0, 0.0, 0.0, 0.0], physicsClientId=c)

        half = CUBE_M / 2
        cube_col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[half] * 3,
                                           physicsClientId=c)
        cube_vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[half] * 3,
                                        rgbaColor=CUBE_RGBA, physicsClientId=c)
        pusher_col = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=PUSHER_RADIUS_M,
                                             height=PUSHER_HEIGHT_M, physicsClientId=c)
        pusher_vis = pb.createVisualShape(pb.GEOM_CYLINDER, radius=PUSHER_RADIUS_M,
                                          length=PUSHER_HEIGHT_M, rgbaColor=PUSHER_RGBA,
                                          physicsClientId=c)
        self.cubes: list[int] = []
        self.pushers: list[int] = []
        self.constraints: list[int] = []
        self._rest: list[tuple[float, float, float]] = []
        self._table: np.ndarray | None = None
        for (x, y), prm in zip(centres, params, strict=True):
            cube = pb.createMultiBody(prm.mass_kg, cube_col, cube_vis,
                                      basePosition=[x, y, half], physicsClientId=c)
            pb.changeDynamics(cube, -1, lateralFriction=prm.friction, restitution=0.0,
                              physicsClientId=c)
            rest = (x, _REST_Y_M, _PUSHER_Z)
            pusher = pb.createMultiBody(_PUSHER_MASS_KG, pusher_col, pusher_vis,
                                        basePosition=rest, physicsClientId=c)
            # Bullet multiplies the two bodies' coefficients: make the pair's be the draw.
            pb.changeDynamics(pusher, -1, lateralFriction=prm.pusher_friction / prm.friction,
                              restitution=0.0, physicsClientId=c)
            pb.setCollisionFilterPair(pusher, self.table, -1, -1, 0, physicsClientId=c)
            cid = pb.createConstraint(pusher, -1, -1, -1, pb.JOINT_FIXED, [0.0, 0.0, 0.0],
                                      [0.0, 0.0, 0.0], rest, physicsClientId=c)
            pb.changeConstraint(cid, rest, maxForce=_PUSHER_FORCE_N, physicsClientId=c)
            self.cubes.append(cube)
            self.pushers.append(pusher)
            self.constraints.append(cid)
            self._rest.append(rest)

    # --- state ---------------------------------------------------------------------------
    def cube_pose(self, arm: int) -> tuple[tuple[float, float, float], float]:
        """World position and yaw of an arm's cube."""
        pos, orn = pb.getBasePositionAndOrientation(self.cubes[arm], physicsClientId=self.client)
        yaw = pb.getEulerFromQuaternion(orn)[2]
        return (pos[0], pos[1], pos[2]), yaw

    def place_cube(self, arm: int, xy: tuple[float, float], yaw: float) -> None:
        """Put an arm's cube flat on the table at rest (a human's hand, or a test)."""
        orn = pb.getQuaternionFromEuler([0.0, 0.0, yaw])
        c = self.client
        pb.resetBasePositionAndOrientation(self.cubes[arm], [xy[0], xy[1], CUBE_M / 2], orn,
                                           physicsClientId=c)
        pb.resetBaseVelocity(self.cubes[arm], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0],
                             physicsClientId=c)

    def rest(self) -> None:
        """Every pusher to its rest pose, out of the camera's view."""
        for arm in range(len(self.pushers)):
            self._teleport_pusher(arm, self._rest[arm])

    def _teleport_pusher(self, arm: int, pos: tuple[float, float, float]) -> None:
        c = self.client
        pb.resetBasePositionAndOrientation(self.pushers[arm], pos, [0.0, 0.0, 0.0, 1.0],
                                           physicsClientId=c)
        pb.resetBaseVelocity(self.pushers[arm], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0],
                             physicsClientId=c)
        pb.changeConstraint(self.constraints[arm], pos, maxForce=_PUSHER_FORCE_N,
                            physicsClientId=c)

    # --- the push primitive ------------------------------------------------------------
    @staticmethod
    def plan_stroke(arm: int, centre: tuple[float, float], direction: tuple[float, float],
                    offset: float) -> Stroke:
        """A face push along the face's inward normal ``direction`` (unit, world), its line
        shifted sideways by ``offset`` metres. Only the part from ``CONTACT_GAP_M`` before
        the face on is integrated: before that the pusher moves through free space (the
        line meets nothing but this face), and starting the stroke from rest just before
        contact is what a careful robot does anyway."""
        dx, dy = direction
        sx, sy = centre[0] - dy * offset, centre[1] + dx * offset

        def back(gap: float) -> tuple[float, float]:
            d = CUBE_M / 2 + PUSHER_RADIUS_M + gap
            return (sx - dx * d, sy - dy * d)

        return Stroke(arm, back(PUSH_START_OFFSET * WORKSPACE_M), back(CONTACT_GAP_M), (sx, sy))

    def run_strokes(self, strokes: Sequence[Stroke]) -> None:
        """Execute all strokes at once, let the cubes settle, and rest the pushers."""
        c = self.client
        for s in strokes:
            self._teleport_pusher(s.arm, (*s.start, _PUSHER_Z))
        for i in range(STROKE_STEPS):
            a = 0.5 - 0.5 * math.cos(math.pi * (i + 1) / STROKE_STEPS)
            for s in strokes:
                target = (s.start[0] + a * (s.end[0] - s.start[0]),
                          s.start[1] + a * (s.end[1] - s.start[1]), _PUSHER_Z)
                pb.changeConstraint(self.constraints[s.arm], target,
                                    maxForce=_PUSHER_FORCE_N, physicsClientId=c)
            pb.stepSimulation(physicsClientId=c)
        # Settle: the pusher holds at the cube's old centre while the cube slides to rest
        # (checked every few steps; a fixed rule, so still deterministic).
        for i in range(1, SETTLE_MAX_STEPS + 1):
            pb.stepSimulation(physicsClientId=c)
            if (i >= SETTLE_MIN_STEPS and i % _SETTLE_CHECK_EVERY == 0
                    and all(self._speed(s.arm) < SETTLE_SPEED_M_S for s in strokes)):
                break
        for s in strokes:
            self._teleport_pusher(s.arm, self._rest[s.arm])

    def _speed(self, arm: int) -> float:
        lin, _ = pb.getBaseVelocity(self.cubes[arm], physicsClientId=self.client)
        return math.hypot(lin[0], lin[1])

    # --- camera ------------------------------------------------------------------------
    def render(self, width: int, height: int, view: Sequence[float],
               proj: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """One TinyRenderer picture: (height, width, 3) uint8 RGB with the table painted
        in, and the (height, width) bool mask of the pixels that show a cube."""
        out = pb.getCameraImage(width, height, view, proj, shadow=0,
                                lightDirection=[0.4, 0.6, 1.0],
                                renderer=pb.ER_TINY_RENDERER, physicsClientId=self.client)
        rgba = np.asarray(out[2], dtype=np.uint8).reshape(height, width, 4)
        seg = np.asarray(out[4]).reshape(height, width)
        if self._table is None or self._table.shape[:2] != (height, width):
            self._table = np.empty((height, width, 3), dtype=np.uint8)
            self._table[:] = TABLE_RGB
        rgb = cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB)
        cv2.copyTo(self._table, (seg < 0).view(np.uint8), rgb)  # numpy's where: 20x slower
        cubes = seg == self.cubes[0]
        for body in self.cubes[1:]:
            cubes |= seg == body
        return rgb, cubes

    def close(self) -> None:
        if self.client >= 0:
            pb.disconnect(physicsClientId=self.client)
            self.client = -1
