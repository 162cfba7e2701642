"""What the console needs to know about an arm's image: the cube and the workspace.

Both come from perception (``testbed.perception.cube``), the same module the fleet loop
judges success and violation with, so the console draws what the loop decides on. It
is imported inside the two functions, not at the top: it loads cv2, and the console
loads cv2 only once a console draws (``gui.desk``, which uses :func:`locate_cube`, stays
pure Python). A picture perception cannot read is "cube not found" (the face markers
then sit around the image centre), never a console failure.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from gui.layout import DEFAULT_CUBE_HALF, CubeMarker
from testbed.core.types import IMAGE_SIZE


def workspace_polygon() -> npt.NDArray[np.float64]:
    """(6, 2) canonical vertices of the workspace (perception's ``WORKSPACE_POLYGON``)."""
    from testbed.perception import cube  # lazy: cv2 (module docstring)

    return np.asarray(cube.WORKSPACE_POLYGON, dtype=np.float64)


def locate_cube(image: npt.NDArray[np.uint8]) -> CubeMarker | None:
    """The cube in an arm's canonical image, or None when perception cannot tell."""
    from testbed.perception import cube  # lazy: cv2 (module docstring)

    try:
        pose = cube.find_cube(image)
    except Exception:  # a picture perception cannot read: no marker, no failure
        return None
    if pose is None:
        return None
    cx, cy = (float(v) for v in pose.centre)
    yaw, area = float(pose.yaw), float(pose.area_px)
    size = image.shape[0] if image.ndim >= 2 and image.shape[0] else IMAGE_SIZE
    half = 0.5 * math.sqrt(area) / size if area > 0 else DEFAULT_CUBE_HALF
    if not all(math.isfinite(v) for v in (cx, cy, yaw, half)):
        return None
    return CubeMarker((cx, cy), yaw, half)
