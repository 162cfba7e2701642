"""The host's overhead camera through OpenCV's VideoCapture (a device or a video file).

Why a wrapper: a live camera hands out frames from a small driver queue, so the newest
frame may be older than the last push; ``read`` drops ``flush_frames`` queued frames
first. A video file (tests, replays) loops at its end instead of running dry. Every
failure is a :class:`~drivers.errors.BackendError` that names the source.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np
import numpy.typing as npt

from drivers.errors import BackendError


class Camera(Protocol):
    """One overhead camera: BGR frames of a fixed size."""

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        ...

    def read(self) -> npt.NDArray[np.uint8]: ...

    def close(self) -> None: ...


class VideoCaptureCamera:
    """``cv2.VideoCapture`` on a device index ("0") or a video file path."""

    def __init__(self, source: str | int, *, flush_frames: int | None = None) -> None:
        import cv2

        self._source = source
        self._is_file = isinstance(source, str) and not source.isdigit()
        if self._is_file and not Path(str(source)).is_file():
            raise BackendError(f"camera: video file {source!r} does not exist")
        index: str | int = int(source) if isinstance(source, str) and source.isdigit() else source
        self._cap = cv2.VideoCapture(index)
        if not self._cap.isOpened():
            raise BackendError(f"camera: cannot open {source!r} with cv2.VideoCapture")
        self._flush = (0 if self._is_file else 2) if flush_frames is None else flush_frames
        w = int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        h = int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if w <= 0 or h <= 0:
            frame = self.read()
            h, w = frame.shape[:2]
        self._size = (w, h)

    @property
    def size(self) -> tuple[int, int]:
        return self._size

    def read(self) -> npt.NDArray[np.uint8]:
        import cv2

        for _ in range(self._flush):
            self._cap.grab()
        ok, frame = self._cap.read()
        if not ok and self._is_file:  # at the end of the file: start it again
            self._cap.release()
            self._cap = cv2.VideoCapture(self._source)
            ok, frame = self._cap.read()
        if not ok or frame is None or frame.ndim != 3 or frame.shape[2] != 3:
            raise BackendError(f"camera {self._source!r} gave no frame")
        return np.ascontiguousarray(frame, dtype=np.uint8)

    def close(self) -> None:
        self._cap.release()
