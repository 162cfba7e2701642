"""Where things are in a console window: one geometry for drawing and for clicking.

The drawing module, the click mapping and the tests' ``xdotool`` clicks must agree to
the pixel on where the image and the face markers are, so the geometry lives here once,
in window coordinates (the frame is shown 1:1: ``WINDOW_AUTOSIZE | WINDOW_GUI_NORMAL``
adds no toolbar and no scaling).

    +------------------------------+  y = 0
    | header: human, arm, why, timer|
    +------------------------------+  y = header_h
    |                              |
    |  arm image, upscaled x scale |  image_px = 64 * scale  (>= 256)
    |  + overlays, face markers    |
    |                              |
    +------------------------------+  y = header_h + image_px
    | footer: keys, status          |
    +------------------------------+  y = height
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from testbed.core.types import FACE_DIRECTIONS, IMAGE_SIZE

Point = tuple[int, int]

MIN_IMAGE_PX = 256
DEFAULT_CUBE_HALF = 4.0 / IMAGE_SIZE
"""Half a cube side in canonical units, used when the cube is not found."""


@dataclass(frozen=True, slots=True)
class CubeMarker:
    """Where the console draws the cube: centre and half side in canonical units."""

    centre: tuple[float, float]
    yaw: float = 0.0
    half: float = DEFAULT_CUBE_HALF
    found: bool = True
    """False: perception did not find the cube; the markers sit around the centre."""


@dataclass(frozen=True, slots=True)
class ConsoleLayout:
    scale: int = 6
    header_h: int = 72
    footer_h: int = 46
    marker_radius: int = 15
    marker_gap: int = 30
    """Pixels between the cube's corner circle and a face marker's centre."""

    def __post_init__(self) -> None:
        if self.image_px < MIN_IMAGE_PX:
            raise ValueError(
                f"scale {self.scale} gives {self.image_px} px; need >= {MIN_IMAGE_PX}"
            )

    @property
    def image_px(self) -> int:
        return IMAGE_SIZE * self.scale

    @property
    def width(self) -> int:
        return self.image_px

    @property
    def height(self) -> int:
        return self.header_h + self.image_px + self.footer_h

    @property
    def image_rect(self) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) of the image in the window, x1/y1 exclusive."""
        return 0, self.header_h, self.image_px, self.header_h + self.image_px

    def to_window(self, xy: tuple[float, float]) -> Point:
        """Canonical [0, 1]^2 -> window pixel."""
        return (
            round(xy[0] * self.image_px),
            self.header_h + round(xy[1] * self.image_px),
        )

    def to_canonical(self, point: tuple[float, float]) -> tuple[float, float]:
        return point[0] / self.image_px, (point[1] - self.header_h) / self.image_px

    def in_image(self, point: tuple[float, float]) -> bool:
        x0, y0, x1, y1 = self.image_rect
        return x0 <= point[0] < x1 and y0 <= point[1] < y1

    def face_points(self, cube: CubeMarker | None) -> tuple[Point, ...]:
        """Window coordinates of face marker k (k = action), for drawing and clicking.

        Marker k sits on the side the cube moves to when action k is pushed
        (``FACE_DIRECTIONS[k]``), like w/a/x/d around s on the keyboard; near an edge
        it is pulled back inside the image.
        """
        cube = cube or CubeMarker((0.5, 0.5), found=False)
        cx, cy = self.to_window(cube.centre)
        reach = cube.half * math.sqrt(2.0) * self.image_px + self.marker_gap
        x0, y0, x1, y1 = self.image_rect
        m = self.marker_radius + 1
        points: list[Point] = []
        for dx, dy in FACE_DIRECTIONS:
            px = min(max(round(cx + dx * reach), x0 + m), x1 - 1 - m)
            py = min(max(round(cy + dy * reach), y0 + m), y1 - 1 - m)
            points.append((px, py))
        return tuple(points)
