"""The PyBullet digital twin of a bimanual pushing cell, and its scripted supervisor.

Why it exists: the fleet controller must be testable and runnable without robots. A
``TwinCell`` behaves like one lab host (two arms, one overhead camera, a cube each) and
keeps the task semantics (success, violation, the 50-push cap: ``sim_twin.constants``);
``supervisor`` is the scripted human that teleoperates with ground truth. This package
imports nothing of the project.
"""

from __future__ import annotations

try:
    from sim_twin.cell import TwinArmState, TwinCell, TwinOutcome
    from sim_twin.constants import (
        FACE_DIRECTIONS,
        IMAGE_SIZE,
        MAX_PUSHES_PER_GOAL,
        MIN_GOAL_DISTANCE,
        NUM_ACTIONS,
        SUCCESS_RADIUS,
        WORKSPACE_POLYGON,
    )
    from sim_twin.supervisor import expert_face
except ModuleNotFoundError as exc:
    if exc.name != "pybullet":
        raise
    # A robot host's install has no PyBullet (docs/setup.md, "Two installs"): one line that names
    # the extra (testbed.core.extras says the same for the controller's rooms; this
    # package imports nothing of the project).
    raise ImportError("sim_twin needs the operator install: pip install "
                      "'fleet-testbed[operator]' (or the twin extra; this is a host "
                      "install: pybullet is not installed)", name="pybullet") from None

__all__ = [
    "FACE_DIRECTIONS",
    "IMAGE_SIZE",
    "MAX_PUSHES_PER_GOAL",
    "MIN_GOAL_DISTANCE",
    "NUM_ACTIONS",
    "SUCCESS_RADIUS",
    "WORKSPACE_POLYGON",
    "TwinArmState",
    "TwinCell",
    "TwinOutcome",
    "expert_face",
]
