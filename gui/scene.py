"""What the console needs to know about an arm's image: the cube and the workspace.

Perception (``testbed.perception.cube``) is another part's module, written in parallel and
free to change; the console must never fail because of it. So it is imported lazily
and any failure degrades to "cube not found" (the face markers then sit around the
image centre) and to the workspace hexagon of DESIGN.md section 3.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from gui.layout import DEFAULT_CUBE_HALF, CubeMarker
from testbed.core.types import IMAGE_SIZE

FALLBACK_WORKSPACE: npt.NDArray[np.float64] = np.array(
    [(0.275, 0.075), (0.925, 0.075), (0.925, 0.725), (0.725, 0.925), (0.075, 0.925),
     (0.075, 0.275)],
    dtype=np.float64,
)
"""DESIGN.md section 3: the square [0.075, 0.925]^2 with two opposite corners cut."""


def _perception() -> Any | None:
    try:
        import testbed.perception.cube as perception  # lazy and optional
    except Exception:  # a half-written module must not take the console down
        return None
    return perception


def workspace_polygon() -> npt.NDArray[np.float64]:
    """(6, 2) canonical vertices of the workspace."""
    perception = _perception()
    poly = getattr(perception, "WORKSPACE_POLYGON", None) if perception else None
    try:
        arr = np.asarray(poly, dtype=np.float64)
    except (TypeError, ValueError):
        return FALLBACK_WORKSPACE
    if poly is None or arr.ndim != 2 or arr.shape[1] != 2:
        return FALLBACK_WORKSPACE
    return arr


def locate_cube(image: npt.NDArray[np.uint8]) -> CubeMarker | None:
    """The cube in an arm's canonical image, or None when perception cannot tell."""
    perception = _perception()
    find = getattr(perception, "find_cube", None) if perception else None
    if find is None:
        return None
    try:
        pose = find(image)
    except Exception:
        return None
    if pose is None:
        return None
    try:
        cx, cy = (float(v) for v in pose.centre)
        yaw = float(getattr(pose, "yaw", 0.0) or 0.0)
        area = float(getattr(pose, "area_px", 0.0) or 0.0)
    except (TypeError, ValueError, AttributeError):
        return None
    size = image.shape[0] if image.ndim >= 2 and image.shape[0] else IMAGE_SIZE
    half = 0.5 * math.sqrt(area) / size if area > 0 else DEFAULT_CUBE_HALF
    if not all(math.isfinite(v) for v in (cx, cy, yaw, half)):
        return None
    return CubeMarker((cx, cy), yaw, half)
