"""Synthetic arm images for the console tests (imported by the tests and conftest)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from testbed.types import HumanRequest

RequestFactory = Callable[..., HumanRequest]
CUBE_RGB = (220, 40, 20)
TABLE_RGB = (190, 190, 185)


def arm_image(cube_px: tuple[int, int] = (24, 32), side: int = 8) -> np.ndarray:
    """A 64x64 RGB table with a red cube whose top-left corner is at ``cube_px``."""
    img = np.full((64, 64, 3), TABLE_RGB, np.uint8)
    x, y = cube_px
    img[y : y + side, x : x + side] = CUBE_RGB
    return img
