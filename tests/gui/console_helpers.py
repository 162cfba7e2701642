"""Synthetic arm images and an ``act`` thread for the console tests (both consoles)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from testbed.core.types import HumanRequest, HumanResponse

RequestFactory = Callable[..., HumanRequest]
CUBE_RGB = (220, 40, 20)
TABLE_RGB = (190, 190, 185)


def arm_image(cube_px: tuple[int, int] = (24, 32), side: int = 8) -> np.ndarray:
    """A 64x64 RGB table with a red cube whose top-left corner is at ``cube_px``."""
    img = np.full((64, 64, 3), TABLE_RGB, np.uint8)
    x, y = cube_px
    img[y : y + side, x : x + side] = CUBE_RGB
    return img


class ActCall:
    """``humans.act`` in a thread, as the fleet loop calls it (it blocks for pushes)."""

    def __init__(self, fn: Callable[[], dict[str, HumanResponse]]) -> None:
        self.result: dict[str, HumanResponse] | None = None
        self.error: BaseException | None = None
        self.t_end: float | None = None

        def run() -> None:
            try:
                self.result = fn()
            except BaseException as exc:  # handed to the test
                self.error = exc
            finally:
                self.t_end = time.monotonic()

        self.thread = threading.Thread(target=run, name="act-call", daemon=True)
        self.thread.start()

    def join(self, timeout: float = 10.0) -> dict[str, HumanResponse]:
        self.thread.join(timeout)
        assert not self.thread.is_alive(), "act() did not return"
        if self.error is not None:
            raise self.error
        assert self.result is not None
        return self.result

    @property
    def waiting(self) -> bool:
        return self.thread.is_alive()
