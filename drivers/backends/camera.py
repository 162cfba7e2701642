"""The host's overhead camera through OpenCV's VideoCapture: a device, a file or a URL.

Why a wrapper: a live camera hands out frames from a queue, so the next frame may be
older than the last push. A device drops ``flush_frames`` queued frames first (its
driver queue is a few frames deep). A network camera (``http://``, ``https://``,
``rtsp://``: a lab IP camera, or the hardware twin's MJPEG stream) queues in the
sockets and in FFmpeg, so ``read`` drains it: it grabs until a grab has to wait for the
camera (longer than half a frame interval), bounded, so the frame returned was produced
after the call started. It is opened with FFmpeg open/read timeouts, so a dead camera
is an error, never a hang. A video file (tests, replays) loops at its end instead of
running dry. Every failure is a :class:`~drivers.errors.BackendError` of one line that
names the source.
"""

from __future__ import annotations

import os
import re
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from drivers.errors import BackendError

URL_SCHEMES = ("http://", "https://", "rtsp://")
"""Sources opened as a network camera (FFmpeg), not as a device or a file."""
_UNSET_VAR = re.compile(r"\$(\w+|\{[^}]*\})")


def expand_path(path: str, what: str) -> str:
    """``~`` and ``$VARS`` expanded as the host's shell would; an unset variable is an
    error naming ``what`` (a silently literal ``$HOME`` path only fails later, unclearly)."""
    out = os.path.expandvars(os.path.expanduser(path))
    if m := _UNSET_VAR.search(out):
        raise BackendError(f"{what}: {path!r}: environment variable {m.group(1).strip('{}')} "
                           f"is not set on this host")
    return out


def is_url(source: str | int) -> bool:
    return isinstance(source, str) and source.lower().startswith(URL_SCHEMES)


class Camera(Protocol):
    """One overhead camera: BGR frames of a fixed size."""

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        ...

    def read(self) -> npt.NDArray[np.uint8]: ...

    def close(self) -> None: ...


class VideoCaptureCamera:
    """``cv2.VideoCapture`` on a device index ("0"), a video file path or a stream URL.

    ``fps``: a network camera's real frame rate, when its stream does not say (FFmpeg
    reports 25 for an MJPEG-over-HTTP stream whatever it runs at); it sets the "a grab
    waited" threshold of the drain. ``max_drain_s`` bounds a drain (a camera faster
    than its decoding is never waited for).
    """

    def __init__(self, source: str | int, *, flush_frames: int | None = None,
                 open_timeout_s: float = 5.0, read_timeout_s: float = 5.0,
                 fps: float | None = None, max_drain_s: float = 2.0) -> None:
        if isinstance(source, str) and not source.isdigit() and not is_url(source):
            source = expand_path(source, "camera")
        self._source = source
        self._url = is_url(source)
        self._is_file = isinstance(source, str) and not source.isdigit() and not self._url
        if self._is_file and not Path(str(source)).is_file():
            raise BackendError(f"camera: video file {source!r} does not exist")
        self._open_timeout_s = open_timeout_s
        self._read_timeout_s = read_timeout_s
        self._max_drain_s = max_drain_s
        self.drained = 0
        """Frames dropped by the last ``read`` of a network camera (for tests and logs)."""
        self._cap = self._open()
        import cv2

        self._flush = (0 if self._is_file or self._url else 2) if flush_frames is None \
            else flush_frames
        reported = float(self._cap.get(cv2.CAP_PROP_FPS) or 0.0)
        rate = fps if fps is not None else (reported if 1.0 <= reported <= 240.0 else 30.0)
        self._wait_s = 0.5 / rate
        w = int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        h = int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if w <= 0 or h <= 0:
            frame = self.read()
            h, w = frame.shape[:2]
        self._size = (w, h)

    def _open(self) -> Any:
        import cv2

        if not self._url:
            src = self._source
            index: str | int = int(src) if isinstance(src, str) and src.isdigit() else src
            cap = cv2.VideoCapture(index)
            if not cap.isOpened():
                raise BackendError(f"camera: cannot open {self._source!r} with cv2.VideoCapture")
            return cap
        params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, round(self._open_timeout_s * 1000),
                  cv2.CAP_PROP_READ_TIMEOUT_MSEC, round(self._read_timeout_s * 1000)]
        why = ""
        for _ in range(2):
            cap = cv2.VideoCapture(str(self._source), cv2.CAP_FFMPEG, params)
            if cap.isOpened():
                return cap
            cap.release()
            why, streams = self._why_not()
            if not streams:
                break
            # It streams now: it was busy a moment ago (the previous client's socket not
            # yet closed on the camera's side, as after an agent restart). Once more.
        raise BackendError(f"camera {self._source}: cannot open the stream within "
                           f"{self._open_timeout_s:g} s ({why})")

    def _why_not(self) -> tuple[str, bool]:
        """Why a stream URL did not open, in one phrase (FFmpeg only logs it), and whether
        the camera streams when asked again."""
        if not str(self._source).lower().startswith(("http://", "https://")):
            return "check the URL and that the camera is on", False
        try:
            with urllib.request.urlopen(str(self._source), timeout=min(
                    self._open_timeout_s, 2.0)) as resp:
                kind = resp.headers.get_content_type()
                return (f"HTTP {resp.status} {kind}: not a stream FFmpeg can read",
                        kind.startswith("multipart/"))
        except urllib.error.HTTPError as exc:
            body = exc.read(200).decode("utf-8", "replace").strip().splitlines()
            return f"HTTP {exc.code}" + (f": {body[0]}" if body else f" {exc.reason}"), False
        except (urllib.error.URLError, OSError) as exc:
            reason = getattr(exc, "reason", exc)
            return f"unreachable: {reason}", False

    @property
    def size(self) -> tuple[int, int]:
        return self._size

    def read(self) -> npt.NDArray[np.uint8]:
        import cv2

        if self._url:
            ok, frame = self._drain_and_read()
        else:
            for _ in range(self._flush):
                self._cap.grab()
            ok, frame = self._cap.read()
            if not ok and self._is_file:  # at the end of the file: start it again
                self._cap.release()
                self._cap = cv2.VideoCapture(self._source)
                ok, frame = self._cap.read()
        if not ok or frame is None or frame.ndim != 3 or frame.shape[2] != 3:
            what = f" within {self._read_timeout_s:g} s" if self._url else ""
            raise BackendError(f"camera {self._source!r} gave no frame{what}")
        return np.ascontiguousarray(frame, dtype=np.uint8)

    def _drain_and_read(self) -> tuple[bool, Any]:
        """Grab until one grab waited for the camera (its frame is newer than this call),
        then decode that one. A stream that broke is reopened once (a restarted camera)."""
        for attempt in range(2):
            t0 = time.monotonic()
            grabbed = 0
            while True:
                t = time.monotonic()
                if not self._cap.grab():
                    if time.monotonic() - t >= 0.9 * self._read_timeout_s:
                        return False, None  # silent for the whole read timeout: dead
                    break  # the stream ended (a restarted camera?)
                grabbed += 1
                now = time.monotonic()
                if now - t > self._wait_s or now - t0 > self._max_drain_s:
                    self.drained = grabbed - 1
                    return self._cap.retrieve()
            if attempt == 0:  # the stream ended: one fresh connection, then give up
                self._cap.release()
                self._cap = self._open()
        return False, None

    def close(self) -> None:
        self._cap.release()
