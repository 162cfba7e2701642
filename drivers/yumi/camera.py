"""The host's overhead camera through OpenCV's VideoCapture: a device, a file or a URL.

Why a wrapper: a live camera hands out frames from a queue, so the next frame may be
older than the last push. A device drops ``flush_frames`` queued frames first (its
driver queue is a few frames deep). A network camera (``http://``, ``https://``,
``rtsp://``: a lab IP camera, or the hardware twin's MJPEG stream) queues in the
sockets and in FFmpeg whenever nobody reads it, so a :class:`StreamReader` thread reads
it all the time (nothing queues up) and ``read`` takes the first frame the reader had
to WAIT for after the call started: that frame was produced after the call. (A first
version drained the queue only when asked; after a push the queue held several frames,
and under CPU load one of them took longer than the "waited" threshold to decode and
was taken as fresh: the rehearsal caught stale pictures, so success was seen a step
late.) It is opened with FFmpeg open/read timeouts, so a dead camera is an error,
never a hang. A video file (tests, replays) loops at its end instead of
running dry. Every failure is a :class:`~drivers.errors.BackendError` of one line that
names the source.
"""

from __future__ import annotations

import os
import re
import statistics
import threading
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

    ``fps``: a network camera's real frame rate, if known (FFmpeg reports 25 for an
    MJPEG-over-HTTP stream whatever it runs at); otherwise the stream reader measures it.
    ``max_drain_s`` is kept for compatibility and unused.
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
        self._reader: StreamReader | None = None
        if self._url:
            self._reader = StreamReader(self._cap, self._open, str(self._source),
                                        self._read_timeout_s, fixed_fps=fps)
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

        if self._reader is not None:
            ok, frame = self._reader.fresh_frame(self._read_timeout_s)
            self.drained = self._reader.skipped
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

    def close(self) -> None:
        if self._reader is not None:
            self._reader.stop()  # it owns the capture: it releases it
        else:
            self._cap.release()


class StreamReader:
    """Reads a network camera's stream all the time, in a thread of its own, so that no
    frame queues up in the sockets or in FFmpeg; hands out the first frame it had to wait
    for after a request started.

    Why a thread: a stream nobody reads fills every buffer on its way, and then telling
    a fresh frame from a queued one by timing alone fails under CPU load (a queued frame
    that is slow to decode looks like one the camera was waited for). Read continuously,
    the queue at any moment is at most the frame in flight, and a frame the reader had to
    wait for ("waited": its grab took longer than half the camera's measured frame
    interval) was sent after the wait began. Cost: decoding every frame the camera sends
    (~3 ms per 640x480 JPEG here, ~5 % of a core at 15 fps).

    Only this thread touches the ``cv2.VideoCapture`` (it is not thread-safe): it grabs,
    and retrieves (colour conversion) only the frame that answers a request. A broken
    stream is reopened once (a restarted camera); then every request fails.
    """

    def __init__(self, cap: Any, reopen: Any, name: str, read_timeout_s: float,
                 fixed_fps: float | None = None) -> None:
        self._cap = cap
        self._reopen = reopen
        self._read_timeout_s = read_timeout_s
        self._fixed_interval = None if fixed_fps is None else 1.0 / fixed_fps
        self._cond = threading.Condition()
        self._intervals: list[float] = []
        self._last_arrival: float | None = None
        self._want_after: float | None = None
        self._result: tuple[bool, Any] | None = None
        self._failed = False
        self._stopping = False
        self.skipped = 0
        """Frames grabbed during the last request that did not count as fresh."""
        self._thread = threading.Thread(target=self._run, name=f"camera {name}", daemon=True)
        self._thread.start()

    def _interval(self) -> float:
        """The camera's frame interval: given, else measured, capped at 1/15 s. The cap
        matters under CPU load: a starved reader sees frames in bursts, the measured
        interval grows, and with it a "waited" threshold no real wait would pass."""
        if self._fixed_interval is not None:
            return self._fixed_interval
        if len(self._intervals) < 3:
            return 1.0 / 30.0  # until measured: a fast camera's (a stricter "waited")
        return min(statistics.median(self._intervals), 1.0 / 15.0)

    def _run(self) -> None:
        reopened = False
        try:
            while not self._stopping:
                t = time.monotonic()
                ok = self._cap.grab()
                now = time.monotonic()
                if self._stopping:
                    return
                if not ok:
                    if reopened or now - t >= 0.9 * self._read_timeout_s:
                        break  # silent for the whole read timeout, or broken twice: dead
                    reopened = True
                    self._cap.release()
                    self._cap = self._reopen()
                    self._last_arrival = None
                    continue
                waited = now - t > 0.5 * self._interval()
                if waited and self._last_arrival is not None:
                    self._intervals = [*self._intervals[-15:], now - self._last_arrival]
                self._last_arrival = now
                with self._cond:
                    want = self._want_after
                if want is None:
                    continue
                if t >= want and waited:
                    result = self._cap.retrieve()
                    with self._cond:
                        self._result = result
                        self._want_after = None
                        self._cond.notify_all()
                else:
                    self.skipped += 1
        except Exception:  # a capture that raises is a dead camera: requests fail
            pass
        finally:
            with self._cond:
                self._failed = True
                self._cond.notify_all()
            self._cap.release()

    def fresh_frame(self, timeout_s: float) -> tuple[bool, Any]:
        """The first frame the reader waits for after now: (ok, BGR image)."""
        with self._cond:
            if self._failed:
                return False, None
            self.skipped = 0
            self._result = None
            self._want_after = time.monotonic()
            deadline = self._want_after + timeout_s
            while self._result is None and not self._failed:
                left = deadline - time.monotonic()
                if left <= 0:
                    self._want_after = None
                    return False, None
                self._cond.wait(left)
            result, self._result = self._result, None
            return result if result is not None else (False, None)

    def stop(self) -> None:
        with self._cond:
            self._stopping = True
        # the grab in progress returns with the next frame (or the read timeout)
        self._thread.join(self._read_timeout_s + 1.0)
