"""Perception: the cube's pose, the goal, success and violation, from the image alone.

Why from the image: on the physical cell nothing else knows where the cube is, and the
fleet loop must decide success and constraint violation the same way in twin and lab
(docs/ARCHITECTURE.md, "The timestep"). So this module sees only a canonical (H, W, 3) uint8
RGB image -- the cube is the largest saturated red/orange blob, the goal the largest
green one -- and uses numpy and cv2 only.

Coordinates are canonical image units (``testbed.core.types``): pixel ``(i, j)`` covers
``[i, i + 1) x [j, j + 1)`` divided by the image size, so a blob centre is its pixel
centroid plus one half, over the size.

The goal disc is painted under the cube (a goal marked on the table): the cube's outline
is always whole, but the cube may hide part of the goal, or all of it once the cube
sits on it -- the fleet loop knows the goal it drew and passes that to ``is_success``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import cv2
import numpy as np
import numpy.typing as npt

from testbed.core.types import SUCCESS_RADIUS

WORKSPACE_POLYGON: Final = np.array(
    [(0.275, 0.075), (0.925, 0.075), (0.925, 0.725), (0.725, 0.925), (0.075, 0.925),
     (0.075, 0.275)], dtype=np.float64)
"""The arm's workspace in canonical units: the square [0.075, 0.925]^2 with its top-left
and bottom-right corners cut. The cube's centre leaving it is a violation. Equal to
``sim_twin.WORKSPACE_POLYGON`` (a test checks; testbed may not import sim_twin)."""
WORKSPACE_POLYGON.setflags(write=False)

# HSV thresholds (OpenCV's hue is 0..179). The cube is saturated red/orange under any
# shading; the table is unsaturated; the goal disc is a saturated green.
CUBE_HUE_RANGES: Final = ((0, 25), (165, 179))
GOAL_HUE_RANGE: Final = (40, 85)
MIN_SATURATION: Final = 110
MIN_VALUE: Final = 50
GOAL_RADIUS: Final = 3.0 / 64.0
"""Radius of the goal disc the hosts paint (canonical units; as sim_twin's)."""
GOAL_RGB: Final = (40, 200, 40)
_GOAL_FIT_STEP_PX: Final = 0.125
MIN_BLOB_PX: Final = 2.0
"""Smaller blobs are noise, not a cube or a goal."""

Image = npt.NDArray[np.uint8]


@dataclass(frozen=True, slots=True)
class CubePose:
    """The cube as seen: centre in canonical units, yaw in ``[-pi/4, pi/4)`` (the angle of
    an edge in image coordinates, x right and y down, modulo a quarter turn), and the
    blob's area in pixels."""

    centre: tuple[float, float]
    yaw: float
    area_px: float


def _mask(image: Image, hue_ranges: tuple[tuple[int, int], ...]) -> npt.NDArray[np.uint8]:
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"expected an (H, W, 3) uint8 RGB image, got {image.shape} "
                         f"{image.dtype}")
    hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)
    mask = np.zeros(image.shape[:2], dtype=np.uint8)
    for lo, hi in hue_ranges:
        mask |= cv2.inRange(hsv, (lo, MIN_SATURATION, MIN_VALUE), (hi, 255, 255))
    return mask


def _largest_blob(mask: npt.NDArray[np.uint8]) -> npt.NDArray[np.int32] | None:
    """Pixel coordinates (N, 2) as (x, y) of the largest 8-connected blob, or None."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if count <= 1:
        return None
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if stats[best, cv2.CC_STAT_AREA] < MIN_BLOB_PX:
        return None
    ys, xs = np.nonzero(labels == best)
    return np.stack([xs, ys], axis=1).astype(np.int32)


def _to_canonical(x: float, y: float, shape: tuple[int, ...]) -> tuple[float, float]:
    return ((x + 0.5) / shape[1], (y + 0.5) / shape[0])


def find_cube(image: Image) -> CubePose | None:
    """The cube's pose from a canonical image, or None if no cube is in view."""
    pts = _largest_blob(_mask(image, CUBE_HUE_RANGES))
    if pts is None:
        return None
    hull = cv2.convexHull(pts)
    m = cv2.moments(hull)
    if m["m00"] >= 4.0:
        cx, cy = m["m10"] / m["m00"], m["m01"] / m["m00"]
    else:  # a sliver (cube at the image border): the pixels' mean is all there is
        cx, cy = (float(v) for v in pts.mean(axis=0))
    (_, _), (_, _), angle = cv2.minAreaRect(hull)
    q = math.pi / 2
    yaw = (math.radians(angle) + q / 2) % q - q / 2
    return CubePose(_to_canonical(cx, cy, image.shape), yaw, float(len(pts)))


def find_goal(image: Image) -> tuple[float, float] | None:
    """The goal disc's centre in canonical units, or None if no goal is visible.

    The disc (radius GOAL_RADIUS) is painted on the table, under the cube. A whole disc
    gives its pixel centroid. When the cube hides part of it, the centre is the one whose
    disc best explains the picture: covering every green pixel, and no pixel that is
    neither green nor cube. When the cube hides all of it (the cube is on the goal),
    nothing is visible and this returns None: the fleet loop knows the goal it drew
    (``ArmObservation.goal``) and decides success with that.
    """
    green = _mask(image, (GOAL_HUE_RANGE,)) > 0
    ys, xs = np.nonzero(green)
    if len(xs) < MIN_BLOB_PX:
        return None
    r = GOAL_RADIUS * image.shape[1]
    mx, my = float(xs.mean()), float(ys.mean())
    h, w = green.shape
    cube = _mask(image, CUBE_HUE_RANGES) > 0
    near_cube = cv2.dilate(cube.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    at_border = xs.min() == 0 or ys.min() == 0 or xs.max() == w - 1 or ys.max() == h - 1
    if not at_border and not (green & near_cube).any():
        return _to_canonical(mx, my, image.shape)  # a whole disc
    free = ~(green | cube)
    x0, x1 = max(int(mx - 2 * r) - 1, 0), min(int(mx + 2 * r) + 3, w)
    y0, y1 = max(int(my - 2 * r) - 1, 0), min(int(my + 2 * r) + 3, h)
    py, px = np.mgrid[y0:y1, x0:x1]
    # cost(c) = green pixels outside disc(c) + free pixels inside it
    #         = const + sum over pixels inside disc(c) of (+1 free, -1 green, 0 cube).
    weight = free[y0:y1, x0:x1].astype(np.float32) - green[y0:y1, x0:x1]
    keep = (weight != 0).ravel()
    cx, cy = px.ravel()[keep] + 0.5, py.ravel()[keep] + 0.5
    weight = weight.ravel()[keep]
    best = np.array([mx, my]) + 0.5
    for half, step in ((r, 0.5), (0.5, _GOAL_FIT_STEP_PX)):  # coarse, then fine
        offs = np.arange(-half, half + 1e-9, step)
        gx, gy = (a.ravel() for a in np.meshgrid(best[0] + offs, best[1] + offs))
        inside = (gx[:, None] - cx) ** 2 + (gy[:, None] - cy) ** 2 <= r * r
        cost = inside.astype(np.float32) @ weight
        low = cost == cost.min()
        best = np.array([gx[low].mean(), gy[low].mean()])
    return (float(best[0]) / w, float(best[1]) / h)


def draw_goal(image: Image, goal: tuple[float, float],
              cube: npt.NDArray[np.bool_] | None = None) -> Image:
    """Paint the goal disc into a canonical image, in place, the way ``find_goal`` reads
    it: the pixels whose centre lies within GOAL_RADIUS of ``goal``, except the cube's
    (``cube``: its pixel mask, e.g. ``cube_mask(image)``). For a host that draws goals
    into real camera crops; the twin draws the same disc itself."""
    h, w = image.shape[:2]
    ys, xs = np.ogrid[0:h, 0:w]
    r = GOAL_RADIUS * w
    paint = (xs + 0.5 - goal[0] * w) ** 2 + (ys + 0.5 - goal[1] * h) ** 2 <= r * r
    if cube is not None:
        paint &= ~cube
    image[paint] = GOAL_RGB
    return image


def cube_mask(image: Image) -> npt.NDArray[np.bool_]:
    """The pixels that look like the cube (the colour threshold of ``find_cube``)."""
    return _mask(image, CUBE_HUE_RANGES) > 0


def workspace_depth(xy: tuple[float, float] | npt.ArrayLike) -> float:
    """Signed distance of a point to the workspace polygon's edges: > 0 inside."""
    p = np.asarray(xy, dtype=np.float64)
    v = WORKSPACE_POLYGON
    e = np.roll(v, -1, axis=0) - v
    n = np.stack([-e[:, 1], e[:, 0]], axis=1) / np.linalg.norm(e, axis=1, keepdims=True)
    # The vertices wind so that these normals point inwards (checked in the tests).
    return float(np.min(np.sum((p - v) * n, axis=1)))


def is_success(pose: CubePose | None, goal: tuple[float, float] | None) -> bool:
    """The cube's centre is within SUCCESS_RADIUS of the goal."""
    if pose is None or goal is None:
        return False
    return math.dist(pose.centre, goal) <= SUCCESS_RADIUS


def is_violation(pose: CubePose | None) -> bool:
    """The cube's centre is outside the workspace polygon, or the cube is out of view."""
    return pose is None or workspace_depth(pose.centre) < 0.0
