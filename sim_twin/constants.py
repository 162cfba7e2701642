"""Numbers that define the twin cell: task semantics, geometry, and randomisation ranges.

Why a copy of the task constants lives here: ``sim_twin`` imports nothing of the
project (docs/ARCHITECTURE.md, "sim_twin"), so it cannot read ``testbed.core.types``. The
values are the same task contract and a test compares the two copies.

Lengths ending in ``_M`` are metres in the PyBullet world; everything else is in
canonical image units (the arm's 64x64 crop is ``[0, 1]^2``, y down).
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

# --- task semantics (same values as testbed.core.types) ----------------------------------
IMAGE_SIZE: Final = 64
NUM_ACTIONS: Final = 4
FACE_DIRECTIONS: Final[tuple[tuple[float, float], ...]] = (
    (0.0, -1.0),  # 0: up
    (-1.0, 0.0),  # 1: left
    (0.0, 1.0),  # 2: down
    (1.0, 0.0),  # 3: right
)
SUCCESS_RADIUS: Final = 6.0 / 64.0
MIN_GOAL_DISTANCE: Final = 12.0 / 64.0
MAX_PUSHES_PER_GOAL: Final = 50


def _frozen(a: npt.ArrayLike) -> npt.NDArray[np.float64]:
    arr = np.asarray(a, dtype=np.float64)
    arr.setflags(write=False)
    return arr


WORKSPACE_POLYGON: Final = _frozen(
    [(0.275, 0.075), (0.925, 0.075), (0.925, 0.725), (0.725, 0.925), (0.075, 0.925),
     (0.075, 0.275)]
)
"""The arm's workspace in canonical units: the square [0.075, 0.925]^2 with its top-left
and bottom-right corners cut (a convex hexagon). The cube's centre leaving it is a
constraint violation."""

# --- task generation -----------------------------------------------------------------
GOAL_MARGIN: Final = 0.12
"""Goals are drawn at least this far inside the workspace polygon, so the straight path
to a goal, and the expert's staircase around it, stays inside the workspace."""
RESET_NOISE: Final = 0.08
"""A hard reset puts the cube at (0.5, 0.5) + U(-RESET_NOISE, RESET_NOISE)^2, any yaw."""
GOAL_RADIUS: Final = 3.0 / 64.0
"""Radius of the filled green goal disc drawn into the image."""
GOAL_RGB: Final = (40, 200, 40)

# --- world geometry (metres) -----------------------------------------------------------
WORKSPACE_M: Final = 0.32
"""Side of one arm's square workspace on the table (one 64x64 crop): 5 mm per pixel."""
GAP_M: Final = WORKSPACE_M / 4
"""Table between two neighbouring workspaces: a cube that overshoots its workspace never
shows in the neighbour's crop."""
CUBE_M: Final = 0.04
"""Cube side: 8 pixels at 64x64."""
PUSHER_RADIUS_M: Final = 0.0125
PUSHER_HEIGHT_M: Final = 0.06
PUSHER_CLEARANCE_M: Final = 0.003
"""The pusher floats this far above the table (it never rubs on it)."""
CAMERA_HEIGHT_M: Final = 2.0
"""Overhead camera height above the table; high and narrow, so the parallax between the
cube's top face and its centre is a fraction of a pixel."""
PUSH_START_OFFSET: Final = 8.0 / 64.0
"""The push primitive starts this far (canonical units) outside the chosen face."""
CONTACT_GAP_M: Final = 0.004
"""The free-space part of the approach is travelled without integrating physics (nothing
can be hit there); the simulated stroke starts this far from the face."""

CUBE_RGBA: Final = (0.92, 0.30, 0.06, 1.0)
TABLE_RGB: Final = (150, 150, 142)
"""The table, painted into the picture's empty pixels (a flat table renders flat)."""
PUSHER_RGBA: Final = (0.25, 0.25, 0.28, 1.0)

# --- physics -----------------------------------------------------------------------------
TIME_STEP_S: Final = 1.0 / 240.0
SOLVER_ITERATIONS: Final = 10
STROKE_STEPS: Final = 40
"""Integration steps of the contact stroke (cosine speed profile, 1/6 s)."""
SETTLE_MIN_STEPS: Final = 8
SETTLE_MAX_STEPS: Final = 48
SETTLE_SPEED_M_S: Final = 0.02
"""After the stroke, the world is stepped until every cube is slower than this."""

# --- per-seed randomisation (ranges of uniform draws, one draw per cube) ---------------
CUBE_MASS_KG: Final = (0.05, 0.20)
CUBE_FRICTION: Final = (0.25, 0.60)
"""Cube-table Coulomb coefficient (the table's own coefficient is 1)."""
PUSHER_FRICTION: Final = (0.20, 0.50)
"""Pusher-cube Coulomb coefficient (combined, as Bullet multiplies the two bodies')."""
PUSH_BIAS: Final = (-0.05, 0.05)
"""Per cube: systematic sideways offset of the push line, in cube sides."""
PUSH_JITTER: Final = (0.03, 0.12)
"""Per cube: half-width of the per-push uniform sideways offset, in cube sides."""
