"""TwinCell: one bimanual pushing cell (one PyBullet world, one camera) with its task.

Why: the twin stands in for a lab cell in tests and in twin mode, so it keeps the task
semantics (``sim_twin.constants``) itself -- the host reports outcomes, as a lab host
would -- and is deterministic in its seed.

    push(faces) ──► plan a stroke per arm (face normal from the cube's real yaw,
                     sideways offset drawn from the arm's stream)
                ──► TwinWorld.run_strokes (all arms at once, settle, pushers to rest)
                ──► per arm: violation? success? 50-push cap?  ──► TwinOutcome
    observe()   ──► one render per state change, crops, goal discs ──► canonical images

Randomness: each arm has two streams spawned from the seed, one for its cube's physical
parameters (fixed for the cell's life) and one for its task (push offsets, goals,
resets), so what one arm does never changes another arm's draws.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import TracebackType

import numpy as np
import numpy.typing as npt

from sim_twin.constants import (
    CUBE_M,
    GOAL_MARGIN,
    MAX_PUSHES_PER_GOAL,
    MIN_GOAL_DISTANCE,
    NUM_ACTIONS,
    RESET_NOISE,
    SUCCESS_RADIUS,
)
from sim_twin.geometry import depth_inside, push_direction, reduce_yaw
from sim_twin.overhead_camera import CellCamera, draw_goal
from sim_twin.supervisor import expert_face
from sim_twin.world import CubeParams, TwinWorld

_GOAL_CANDIDATES = 64


@dataclass(frozen=True, slots=True)
class TwinOutcome:
    """What one arm's push did. ``soft_reset``: a new goal was drawn after this push
    (after a success, or after the 50th push without one)."""

    success: bool
    violation: bool
    soft_reset: bool


@dataclass(frozen=True, slots=True)
class TwinArmState:
    """Ground truth of one arm in canonical coordinates (image units, y down).

    ``cube_xy`` is where the cube's centre appears in the arm's image; ``yaw`` is its
    canonical yaw reduced into ``[-pi/4, pi/4)``."""

    cube_xy: tuple[float, float]
    yaw: float
    goal_xy: tuple[float, float]
    violating: bool
    pushes_since_goal: int


@dataclass(slots=True)
class _Task:
    rng: np.random.Generator
    params: CubeParams
    goal: tuple[float, float] = (0.5, 0.5)
    violating: bool = False
    pushes: int = 0


class TwinCell:
    """One twin host: a bimanual cell in its own PyBullet DIRECT world.

    Not thread-safe; one cell per process is the host agent's use, many per process is
    fine for tests and benchmarks (each has its own PyBullet client).
    """

    def __init__(self, seed: int, arms: Sequence[str] = ("left", "right"),
                 mirror: Sequence[bool] = (False, True), image_size: int = 64, *,
                 render_scale: int = 1) -> None:
        names = tuple(arms)
        if not names or len(set(names)) != len(names) or not all(names):
            raise ValueError(f"arms must be distinct non-empty names, got {names!r}")
        if len(mirror) != len(names):
            raise ValueError(f"mirror has {len(mirror)} entries for {len(names)} arms")
        if image_size < 16 or image_size % 4:
            raise ValueError(f"image_size must be a multiple of 4 >= 16, got {image_size}")
        if render_scale < 1:
            raise ValueError(f"render_scale must be >= 1, got {render_scale}")
        self.arm_names: tuple[str, ...] = names
        self.seed = seed
        self._index = {name: i for i, name in enumerate(names)}
        self._camera = CellCamera(tuple(bool(m) for m in mirror), image_size, render_scale)
        self._view, self._proj = self._camera.matrices()

        streams = np.random.SeedSequence(seed % 2**64).spawn(len(names))
        self._tasks: list[_Task] = []
        for ss in streams:
            params_ss, task_ss = ss.spawn(2)
            params = CubeParams.draw(np.random.default_rng(params_ss))
            self._tasks.append(_Task(np.random.default_rng(task_ss), params))
        n = len(names)
        self._world = TwinWorld([self._camera.workspace_centre(i) for i in range(n)],
                                [t.params for t in self._tasks])
        self._picture: tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]] | None = None
        for i in range(n):
            self._hard_reset(i)

    # --- the host API ----------------------------------------------------------------
    def observe(self) -> dict[str, npt.NDArray[np.uint8]]:
        """Every arm's (image_size, image_size, 3) uint8 canonical image, goal drawn in."""
        picture, cubes = self._render()
        cam = self._camera
        return {name: draw_goal(cam.crop(picture, i), self._tasks[i].goal,
                                under=cam.crop_mask(cubes, i))
                for i, name in enumerate(self.arm_names)}

    def refresh(self) -> None:
        """Render the camera again now. The cell renders lazily, once after each change of
        the world; a host that wants a new frame regardless (and the benchmark) calls this."""
        self._picture = None
        self._render()

    def picture(self) -> npt.NDArray[np.uint8]:
        """The whole cell camera picture, (H, W, 3) uint8 RGB, no goals (for previews)."""
        return self._render()[0].copy()

    def push(self, faces: Mapping[str, int]) -> dict[str, TwinOutcome]:
        """Push the given arms' cubes at once; face ``k`` moves the cube about along
        ``FACE_DIRECTIONS[k]`` in the arm's canonical frame. A violating arm's push is
        refused (no motion, all-False outcome)."""
        strokes = []
        refused = TwinOutcome(False, False, False)
        outcomes: dict[str, TwinOutcome] = {}
        for arm, face in faces.items():
            i = self._arm(arm)
            if not 0 <= int(face) < NUM_ACTIONS or int(face) != face:
                raise ValueError(f"face must be an int in 0..{NUM_ACTIONS - 1}, got {face!r}")
            task = self._tasks[i]
            outcomes[arm] = refused
            if task.violating:
                continue
            pos, world_yaw = self._world.cube_pose(i)
            d = push_direction(int(face), self._camera.canonical_yaw(i, world_yaw))
            jitter = task.params.push_jitter
            offset = CUBE_M * (task.params.push_bias + float(task.rng.uniform(-jitter, jitter)))
            strokes.append(self._world.plan_stroke(
                i, (pos[0], pos[1]), self._camera.world_vector(i, (d[0], d[1])), offset))
        if strokes:
            self._world.run_strokes(strokes)
            self._picture = None
        for s in strokes:
            outcomes[self.arm_names[s.arm]] = self._judge(s.arm)
        return outcomes

    def hard_reset(self, arm: str) -> None:
        """A human puts the cube back near the centre (noise), with a new goal."""
        self._hard_reset(self._arm(arm))

    def rest(self) -> None:
        """Every pusher to its rest pose, out of the camera's view (they rest there
        between pushes anyway; this is the host's safe state)."""
        self._world.rest()

    def expert_action(self, arm: str) -> int:
        """The scripted supervisor's teleop choice for this arm (ground truth)."""
        s = self.arm_state(arm)
        return expert_face(s.cube_xy, s.yaw, s.goal_xy)

    def arm_state(self, arm: str) -> TwinArmState:
        i = self._arm(arm)
        t = self._tasks[i]
        xy, yaw = self._cube_canonical(i)
        return TwinArmState(xy, yaw, t.goal, t.violating, t.pushes)

    def set_arm_state(self, arm: str, cube_xy: Sequence[float], yaw: float,
                      goal_xy: Sequence[float], *, pushes_since_goal: int = 0) -> None:
        """Construct a state (tests): cube centre at canonical ``cube_xy`` with canonical
        ``yaw``, the goal, the push count; violating iff the cube is outside."""
        i = self._arm(arm)
        self._place(i, (float(cube_xy[0]), float(cube_xy[1])), float(yaw))
        t = self._tasks[i]
        t.goal = (float(goal_xy[0]), float(goal_xy[1]))
        t.pushes = int(pushes_since_goal)
        t.violating = bool(depth_inside(self._cube_canonical(i)[0]) < 0)

    def close(self) -> None:
        self._world.close()

    def __enter__(self) -> TwinCell:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    @property
    def camera(self) -> CellCamera:
        return self._camera

    @property
    def physics_client(self) -> int:
        """The PyBullet client id of this cell's world (benchmarks, debugging)."""
        return self._world.client

    @property
    def camera_matrices(self) -> tuple[list[float], list[float]]:
        return self._view, self._proj

    def cube_params(self, arm: str) -> CubeParams:
        """The physical parameters this seed drew for an arm's cube."""
        return self._tasks[self._arm(arm)].params

    # --- internals ---------------------------------------------------------------------
    def _arm(self, arm: str) -> int:
        if self._world.client < 0:
            raise RuntimeError("the TwinCell is closed")
        try:
            return self._index[arm]
        except KeyError:
            raise KeyError(f"unknown arm {arm!r}; this cell has {self.arm_names}") from None

    def _render(self) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]:
        """The cell picture and its cube mask, rendered once per change of the world."""
        if self._world.client < 0:
            raise RuntimeError("the TwinCell is closed")
        if self._picture is None:
            cam = self._camera
            self._picture = self._world.render(cam.width, cam.height, self._view, self._proj)
        return self._picture

    def _cube_canonical(self, i: int) -> tuple[tuple[float, float], float]:
        pos, world_yaw = self._world.cube_pose(i)
        return (self._camera.to_canonical(i, pos),
                reduce_yaw(self._camera.canonical_yaw(i, world_yaw)))

    def _place(self, i: int, xy: tuple[float, float], yaw: float) -> None:
        self._world.place_cube(i, self._camera.to_world(i, xy, CUBE_M / 2),
                               self._camera.world_yaw(i, yaw))
        self._picture = None

    def _judge(self, i: int) -> TwinOutcome:
        t = self._tasks[i]
        xy, _ = self._cube_canonical(i)
        if depth_inside(xy) < 0:
            t.violating = True
            return TwinOutcome(success=False, violation=True, soft_reset=False)
        if math.dist(xy, t.goal) <= SUCCESS_RADIUS:
            self._new_goal(i, xy)
            return TwinOutcome(success=True, violation=False, soft_reset=True)
        t.pushes += 1
        if t.pushes >= MAX_PUSHES_PER_GOAL:
            self._new_goal(i, xy)
            return TwinOutcome(success=False, violation=False, soft_reset=True)
        return TwinOutcome(success=False, violation=False, soft_reset=False)

    def _hard_reset(self, i: int) -> None:
        t = self._tasks[i]
        xy = tuple(0.5 + t.rng.uniform(-RESET_NOISE, RESET_NOISE, size=2))
        yaw = float(t.rng.uniform(-math.pi / 4, math.pi / 4))
        self._place(i, (float(xy[0]), float(xy[1])), yaw)
        t.violating = False
        self._new_goal(i, self._cube_canonical(i)[0])

    def _new_goal(self, i: int, cube_xy: tuple[float, float]) -> None:
        """A goal inside the workspace (with margin), at least MIN_GOAL_DISTANCE away."""
        t = self._tasks[i]
        t.pushes = 0
        cand = t.rng.uniform(0.0, 1.0, size=(_GOAL_CANDIDATES, 2))
        far = np.linalg.norm(cand - np.asarray(cube_xy), axis=1)
        ok = (depth_inside(cand) >= GOAL_MARGIN) & (far >= MIN_GOAL_DISTANCE)
        if ok.any():
            g = cand[int(np.argmax(ok))]
        else:  # practically never: the farthest candidate well inside the workspace
            inside = depth_inside(cand) >= GOAL_MARGIN
            g = cand[int(np.argmax(np.where(inside, far, -1.0)))]
        t.goal = (float(g[0]), float(g[1]))
