"""The cell's overhead camera: one picture for all arms, cut into canonical crops.

Why this shape: the lab has one camera per bimanual cell, so the twin renders the whole
cell once per timestep (one TinyRenderer call, the expensive part) and cuts it up:

    world ──getCameraImage──► cell picture (H x W) ──crop arm i──► mirror? ──► resize
          ──► draw goal disc (software, like the lab) ──► (64, 64, 3) uint8, canonical

The camera looks straight down (image plane parallel to the table), so the table maps
to the picture by a similarity and every workspace square is an exact pixel square.
The same pinhole model maps world points to canonical coordinates and back, which is
how the cell reports ground truth in the units the task is defined in (image units).

Layout: arm ``i`` of ``n`` has its workspace centred at world
``x = (i - (n - 1) / 2) * (WORKSPACE_M + GAP_M)``, ``y = 0``; the camera is above the
middle. Canonical ``x`` follows world ``+x`` (mirrored arms: ``-x``); canonical ``y``
(down) follows world ``-y``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeVar

import cv2
import numpy as np
import numpy.typing as npt
import pybullet as pb

from sim_twin.constants import CAMERA_HEIGHT_M, GAP_M, GOAL_RADIUS, GOAL_RGB, WORKSPACE_M

UInt8Array = npt.NDArray[np.uint8]
_T = TypeVar("_T", bound=np.generic)

_NEAR_M = 0.5
_FAR_M = CAMERA_HEIGHT_M + 0.5
_PIXEL_SHIFT = 0.5
"""TinyRenderer samples pixel (i, j) at the projected point (i - 1/2, j + 1/2) of the ideal
camera (measured against rendered cubes); the model adds it so ground truth and image
agree."""


@dataclass(frozen=True, slots=True)
class CellCamera:
    """Pinhole model of the cell camera plus the crop layout of its arms."""

    mirror: tuple[bool, ...]
    image_size: int
    render_scale: int = 1

    @property
    def workspace_px(self) -> int:
        return self.image_size * self.render_scale

    @property
    def gap_px(self) -> int:
        return self.workspace_px // 4

    @property
    def width(self) -> int:
        n = len(self.mirror)
        return n * self.workspace_px + (n - 1) * self.gap_px

    @property
    def height(self) -> int:
        return self.workspace_px

    def crop_x0(self, arm: int) -> int:
        """First picture column of an arm's crop."""
        return arm * (self.workspace_px + self.gap_px)

    def workspace_centre(self, arm: int) -> tuple[float, float]:
        """World (x, y) of the centre of an arm's workspace."""
        n = len(self.mirror)
        return ((arm - (n - 1) / 2) * (WORKSPACE_M + GAP_M), 0.0)

    def matrices(self) -> tuple[list[float], list[float]]:
        """PyBullet view and projection matrices of this camera."""
        view = pb.computeViewMatrix([0.0, 0.0, CAMERA_HEIGHT_M], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        fov = math.degrees(2.0 * math.atan(0.5 * WORKSPACE_M / CAMERA_HEIGHT_M))
        proj = pb.computeProjectionMatrixFOV(fov, self.width / self.height, _NEAR_M, _FAR_M)
        return list(view), list(proj)

    # --- world <-> canonical --------------------------------------------------------
    def _px_per_m(self, z: float) -> float:
        return self.workspace_px / WORKSPACE_M * CAMERA_HEIGHT_M / (CAMERA_HEIGHT_M - z)

    def to_canonical(self, arm: int, world: Sequence[float]) -> tuple[float, float]:
        """Canonical (x, y) of a world point (x, y, z) seen through this arm's crop."""
        x, y, z = world[0], world[1], world[2]
        k = self._px_per_m(z)
        u = 0.5 * self.width + k * x + _PIXEL_SHIFT
        v = 0.5 * self.height - k * y - _PIXEL_SHIFT
        cx = (u - self.crop_x0(arm)) / self.workspace_px
        cy = v / self.workspace_px
        return (1.0 - cx if self.mirror[arm] else cx, cy)

    def to_world(self, arm: int, canonical: Sequence[float], z: float) -> tuple[float, float]:
        """World (x, y) of the point at height ``z`` seen at canonical coordinates."""
        cx = 1.0 - canonical[0] if self.mirror[arm] else canonical[0]
        u = self.crop_x0(arm) + cx * self.workspace_px
        v = canonical[1] * self.workspace_px
        k = self._px_per_m(z)
        return ((u - _PIXEL_SHIFT - 0.5 * self.width) / k,
                (0.5 * self.height - v - _PIXEL_SHIFT) / k)

    def world_vector(self, arm: int, canonical: Sequence[float]) -> tuple[float, float]:
        """A canonical direction as a world (x, y) direction (same length)."""
        sx = -1.0 if self.mirror[arm] else 1.0
        return (sx * canonical[0], -canonical[1])

    def canonical_yaw(self, arm: int, world_yaw: float) -> float:
        """Canonical angle of the world direction at ``world_yaw`` (not reduced)."""
        sx = -1.0 if self.mirror[arm] else 1.0
        return math.atan2(-math.sin(world_yaw), sx * math.cos(world_yaw))

    def world_yaw(self, arm: int, canonical_yaw: float) -> float:
        """World yaw of the canonical direction at ``canonical_yaw``."""
        wx, wy = self.world_vector(arm, (math.cos(canonical_yaw), math.sin(canonical_yaw)))
        return math.atan2(wy, wx)

    # --- pictures ----------------------------------------------------------------------
    def crop(self, picture: UInt8Array, arm: int) -> UInt8Array:
        """An arm's canonical (image_size, image_size, 3) crop of the (H, W, 3) picture."""
        out = self._cut(picture, arm)
        if self.render_scale != 1:
            return cv2.resize(out, (self.image_size, self.image_size),
                              interpolation=cv2.INTER_AREA)
        return out.copy()  # always a new array: the goal is drawn into it

    def crop_mask(self, mask: npt.NDArray[np.bool_], arm: int) -> npt.NDArray[np.bool_]:
        """The same crop of a (H, W) bool mask (a pixel is set if mostly covered)."""
        out = self._cut(mask, arm)
        if self.render_scale != 1:
            small = cv2.resize(out.astype(np.uint8) * 255, (self.image_size, self.image_size),
                               interpolation=cv2.INTER_AREA)
            return small > 127
        return np.ascontiguousarray(out)

    def _cut(self, a: npt.NDArray[_T], arm: int) -> npt.NDArray[_T]:
        x0 = self.crop_x0(arm)
        out = a[:, x0:x0 + self.workspace_px]
        return out[:, ::-1] if self.mirror[arm] else out


def draw_goal(image: UInt8Array, goal: Sequence[float],
              under: npt.NDArray[np.bool_] | None = None) -> UInt8Array:
    """Paint the goal as a filled green disc at canonical ``goal``, in place, but not over
    the pixels in ``under`` (the cube): a goal marked on the table, the cube on top of
    it, so the goal never hides the cube's outline from perception.

    The disc is exactly the pixels whose centre lies within GOAL_RADIUS of the goal
    (perception fits that same model when the cube hides part of the disc).
    """
    h, w = image.shape[:2]
    gx, gy = goal[0] * w, goal[1] * h
    r = GOAL_RADIUS * w
    x0, x1 = max(math.floor(gx - r), 0), min(math.ceil(gx + r) + 1, w)
    y0, y1 = max(math.floor(gy - r), 0), min(math.ceil(gy + r) + 1, h)
    if x0 >= x1 or y0 >= y1:
        return image
    ys, xs = np.ogrid[y0:y1, x0:x1]
    paint = (xs + 0.5 - gx) ** 2 + (ys + 0.5 - gy) ** 2 <= r * r
    if under is not None:
        paint &= ~under[y0:y1, x0:x1]
    image[y0:y1, x0:x1][paint] = GOAL_RGB
    return image
