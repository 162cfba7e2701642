"""Is the camera's picture usable: sharpness and exposure of a picture or one arm's crop.

Why: perception finds the cube by its colour in each arm's crop, so a blurred crop
(focus off, or autofocus hunting), an underexposed one (colours sink into noise) or a
clipped one (a saturated channel shifts the hue) fails it quietly: success is missed or
a cube is lost. ``testbed check`` prints these figures per crop so a person sees the
problem before a trial, next to the settings the camera read back.

This module imports cv2 and numpy only (no drivers, no testbed), so any room that may
reach the drivers can use it on a picture it has.

- ``sharpness``: the variance of the Laplacian of the luma (3x3 aperture): higher is
  sharper. A relative figure: compare one camera's crops over time, or against the same
  scene in focus, not across cameras or crop sizes (noise raises it too).
- ``luma_mean`` and ``luma_p1 .. luma_p99``: BT.601 luma, 0..255.
- ``clipped_high``: the fraction of pixels with any channel >= 254 (one saturated
  channel is enough to change a colour's hue); ``clipped_low``: all channels <= 1;
  ``clipped``: both together.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

CLIP_HIGH = 254
CLIP_LOW = 1
PERCENTILES = (1, 5, 50, 95, 99)


class _Camera(Protocol):
    """What :func:`camera_report` needs of a camera (``drivers.cameras.camera.Camera``)."""

    @property
    def size(self) -> tuple[int, int]: ...

    def read(self) -> npt.NDArray[np.uint8]: ...


def sharpness_and_exposure(crop_bgr: npt.NDArray[np.uint8]) -> dict[str, float | int]:
    """The figures of the module docstring for one BGR picture or crop (or a grey one)."""
    import cv2

    img = np.asarray(crop_bgr)
    grey = img.ndim == 2
    bgr = img.ndim == 3 and img.shape[2] == 3
    if img.size == 0 or img.dtype != np.uint8 or not (grey or bgr):
        raise ValueError(f"need a non-empty uint8 BGR (H, W, 3) or grey (H, W) picture, "
                         f"got shape {img.shape} {img.dtype}")
    colour = img[:, :, None] if grey else img
    luma = img if grey else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    lap = cv2.Laplacian(luma, cv2.CV_64F)
    pct = np.percentile(luma, PERCENTILES)
    high = float(np.mean(np.any(colour >= CLIP_HIGH, axis=2)))
    low = float(np.mean(np.all(colour <= CLIP_LOW, axis=2)))
    out: dict[str, float | int] = {"sharpness": round(float(lap.var()), 2),
                                   "luma_mean": round(float(luma.mean()), 2)}
    out.update({f"luma_p{p}": round(float(v), 1) for p, v in zip(PERCENTILES, pct,
                                                                 strict=True)})
    out.update(clipped_high=round(high, 5), clipped_low=round(low, 5),
               clipped=round(high + low, 5), pixels=int(luma.size))
    return out


def camera_report(camera: _Camera, crops: Mapping[str, tuple[int, int, int, int]]
                  | None = None, frame: npt.NDArray[np.uint8] | None = None
                  ) -> dict[str, Any]:
    """One picture's worth of facts for ``testbed check``: the camera's own account
    (``describe()``: source, node, settings asked and read back, refused ones) when it
    has one, the picture's size, how long the read took, the figures of the whole
    picture and, per named crop box (x0, y0, x1, y1), of that crop. JSON-ready.

    ``frame``: a picture already taken (the YuMi backend's, with every arm out of view);
    without one the camera is read here (``read_ms`` is then that read's time, else None).
    """
    describe = getattr(camera, "describe", None)
    read_ms = None
    if frame is None:
        t0 = time.monotonic()
        frame = camera.read()
        read_ms = round((time.monotonic() - t0) * 1000.0, 1)
    h, w = frame.shape[:2]
    out: dict[str, Any] = {"camera": describe() if callable(describe) else {},
                           "size": [int(w), int(h)], "read_ms": read_ms,
                           "picture": sharpness_and_exposure(frame)}
    if crops:
        out["crops"] = {}
        for name, (x0, y0, x1, y1) in crops.items():
            if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
                out["crops"][name] = {"error": f"crop {(x0, y0, x1, y1)} is outside the "
                                               f"{w}x{h} picture"}
                continue
            out["crops"][name] = sharpness_and_exposure(frame[y0:y1, x0:x1])
    return out
