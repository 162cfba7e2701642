"""The host's overhead camera through OpenCV's VideoCapture: a device, a file or a URL.

Why a wrapper: a live camera hands out frames from a queue, so the next frame may be
older than the last push, and a lab names its camera in several ways. Every failure is
a :class:`~drivers.errors.BackendError` of one line that names the source.

What ``camera`` may be, in the order it is tried:

- an ``http://``, ``https://`` or ``rtsp://`` URL: a network camera (a lab IP camera, the
  hardware twin's MJPEG stream), read with FFmpeg open/read timeouts (a dead camera is an
  error, never a hang). It queues in the sockets and in FFmpeg whenever nobody reads it,
  so a :class:`StreamReader` thread reads it all the time and ``read`` takes the first
  frame the reader had to WAIT for after the call started: that frame was produced after
  the call. (A first version drained the queue only when asked; under CPU load a queued
  frame that was slow to decode was taken as fresh: the rehearsal caught stale pictures.)
- a V4L2 device: an index (``"0"``), a path under ``/dev`` (``/dev/video4``, or a
  ``/dev/v4l/by-id/...`` / ``by-path/...`` link, resolved) or a card name (``"HD Pro
  Webcam C920"``); which node, and which are refused (a RealSense's depth stream), is
  :mod:`drivers.cameras.v4l2_devices`' rule. Opened with OpenCV's V4L2 backend; the host's
  ``camera_settings`` are set and read back first (:mod:`drivers.cameras.capture_settings`).
- an existing file: a video (tests, replays) that loops at its end.
- anything else with a ``/`` or a video suffix is a missing file; the rest is looked up
  as a card name, and an error lists this host's nodes.

A device's freshness rule (``read``). OpenCV's V4L2 backend keeps ``CAP_PROP_BUFFERSIZE``
driver buffers (4) queued; while nobody reads, the driver fills them and then drops new
frames, so after a push the queue holds the frames taken just after the previous read.
(The old rule, drop 2 then read, returned the third of those: a frame from before the
push.) The kernel stamps each buffer (UVC: the start of exposure, on CLOCK_MONOTONIC,
Python's ``time.monotonic``), so ``read`` grabs, without decoding, until a frame's stamp
is not before the call, and decodes only that one: the stale frames cost microseconds
each, and the answer is the first frame exposed after the call (about one frame interval
plus its transfer). Stamps are checked: none (0), from the future (another clock) or
still before the call after ``buffers + 3`` grabs (a clock that is not the host's) turn
them off for this camera, and every read then grabs ``buffers + 1`` frames: the driver
held at most ``buffers`` frames, or ``buffers - 1`` and one in flight, from before the
call, so the last one began after it (slower: up to ``buffers + 1`` frame intervals
when the queue was not full). No thread: a background grab loop would need the same
stamps to tell a fresh frame from a just-queued one (the stream reader's "waited" rule
is the timing guess that failed under load), and would make the capture, which is not
thread-safe, shared.

Over 450 lines, on purpose: one camera's every source kind (device, file, URL, stream)
and the rule that no frame older than the last push is believed, read together when a
camera misbehaves.
"""

from __future__ import annotations

import logging
import math
import os
import re
import statistics
import sys
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from drivers.cameras.capture_settings import CaptureSettings, configure
from drivers.cameras.frozen_frames import FROZEN_S, FrozenWatch
from drivers.cameras.v4l2_devices import V4l2Devices, V4l2Node
from drivers.errors import BackendError

URL_SCHEMES = ("http://", "https://", "rtsp://")
"""Sources opened as a network camera (FFmpeg), not as a device or a file."""
VIDEO_SUFFIXES = frozenset({".avi", ".mp4", ".mkv", ".mov", ".webm", ".mjpg", ".mjpeg",
                            ".mpg", ".mpeg", ".m4v", ".ts", ".h264", ".wmv", ".ogv"})
"""A source with one of these suffixes is a video file, never a card name."""
DEFAULT_BUFFERS = 4
"""OpenCV's V4L2 driver queue when the device does not say (DEFAULT_V4L_BUFFERS)."""
STRADDLE_FRAMES = 2
"""Grabs past ``buffers + 1`` allowed for a frame stamped after the call: the frame in
transfer at the call began its exposure before it."""
CLOCK_SLACK_S = 0.05
"""A stamp this far past ``time.monotonic()`` is still this clock (rounding, scheduling)."""
_UNSET_VAR = re.compile(r"\$(\w+|\{[^}]*\})")

CaptureFactory = Callable[..., Any]
"""``factory(source[, api_preference[, params]]) -> capture``: what builds the capture,
``cv2.VideoCapture`` unless a test stands a fake device in (the constructor seam)."""

log = logging.getLogger(__name__)
log.setLevel(logging.INFO)
"""Its INFO lines (a device's timestamps turned off: once per camera) belong in the host
log, whose agent logs others' records from WARNING up (``drivers/agent.py``)."""


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
    """``cv2.VideoCapture`` on a stream URL, a V4L2 device or a video file (module
    docstring: which source is which, and how each read stays fresh).

    ``fps``: a network camera's real frame rate, if known (FFmpeg reports 25 for an
    MJPEG-over-HTTP stream whatever it runs at); otherwise the stream reader measures it.
    ``flush_frames``: frames dropped before each read of a file (default 0) or, instead of
    the freshness rule, of a device (tests of the old behaviour). ``settings``: the host's
    ``camera_settings`` (a device only; a URL with settings is an error, a file ignores
    them with a warning). ``capture`` and ``devices``: the seams where the tests stand in a
    fake ``cv2.VideoCapture`` and a fake ``/dev`` and sysfs. ``max_drain_s`` is kept for
    compatibility and unused.
    """

    def __init__(self, source: str | int, *, flush_frames: int | None = None,
                 open_timeout_s: float = 5.0, read_timeout_s: float = 5.0,
                 fps: float | None = None, max_drain_s: float = 2.0,
                 settings: CaptureSettings | Mapping[str, Any] | str | None = None,
                 capture: CaptureFactory | None = None,
                 devices: V4l2Devices | None = None) -> None:
        self._factory = capture
        self._devices = devices if devices is not None else V4l2Devices()
        self._settings = CaptureSettings.parse(settings)
        self._open_timeout_s = open_timeout_s
        self._read_timeout_s = read_timeout_s
        self._max_drain_s = max_drain_s
        self._node: V4l2Node | None = None
        self._source: str | int = source
        self._kind = self._classify(source)
        self._url = self._kind == "stream"
        self._name = self._label()
        self._flush = flush_frames if flush_frames is not None or self._kind != "file" else 0
        self._use_stamps = True
        self.drained = 0
        """Frames dropped by the last ``read`` (for tests and logs)."""
        self._read_back: dict[str, Any] = {}
        self._refused: dict[str, str] = {}
        self._cap = self._open()
        self._reader: StreamReader | None = None
        self._size = self._start(fps)

    # -- which source ------------------------------------------------------------------
    def _classify(self, source: str | int) -> str:
        """The source's kind, "stream", "device" or "file"; a device resolved to its node
        (the module docstring's order)."""
        if is_url(source):
            if self._settings.asked():
                raise BackendError(f"camera {source}: camera_settings are for a V4L2 device; "
                                   "set a network camera's picture on the camera itself")
            return "stream"
        text = str(source).strip()
        if isinstance(source, int) or text.isdigit():
            self._node = self._devices.by_number(int(text), text)
            return "device"
        path = expand_path(text, "camera")
        if self._devices.is_device_path(path):
            self._node = self._devices.by_path(path)
            return "device"
        if Path(path).is_file():
            self._source = path
            return "file"
        if "/" in path or Path(path).suffix.lower() in VIDEO_SUFFIXES:
            raise BackendError(f"camera: video file {path!r} does not exist")
        node = self._devices.by_card(path)
        if node is None:
            raise BackendError(f"camera {text!r}: no such video file, and no V4L2 device has "
                               f"that card name ({self._devices.listing()}); give a device "
                               "index, /dev/videoN, a /dev/v4l/by-id link, a card name, a "
                               "video file or a URL")
        self._node = node
        return "device"

    def _label(self) -> str:
        """The camera in messages: its source, and its node when that is another name."""
        if self._node is None:
            return str(self._source)
        node = self._node.label()
        return node if str(self._source) == self._node.path else f"{self._source} = {node}"

    def _new_capture(self, *args: Any) -> Any:
        if self._factory is not None:
            return self._factory(*args)
        import cv2

        return cv2.VideoCapture(*args)

    # -- opening -----------------------------------------------------------------------
    def _open(self) -> Any:
        if self._kind == "device":
            return self._open_device()
        if self._kind == "file":
            cap = self._new_capture(self._source)
            if not cap.isOpened():
                raise BackendError(f"camera: cannot open {self._source!r} with cv2.VideoCapture")
            return cap
        return self._open_stream()

    def _open_device(self) -> Any:
        """OpenCV's V4L2 backend on the node. Its wait for a frame is
        ``OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT`` seconds (10 unless set, read once per
        process): set to the read timeout here unless the host set it, so a camera that
        stops sending is an error within it, as a stream is."""
        import cv2

        node = self._node
        assert node is not None
        os.environ.setdefault("OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT",
                              str(max(1, math.ceil(self._read_timeout_s))))
        api = cv2.CAP_V4L2 if sys.platform.startswith("linux") else cv2.CAP_ANY
        cap = self._new_capture(node.number, api)
        if cap.isOpened():
            return cap
        cap.release()
        if not os.path.exists(node.path):
            why = "no such node (unplugged?)"
        elif not os.access(node.path, os.R_OK | os.W_OK):
            why = "permission denied (the agent's user needs the 'video' group)"
        else:
            why = "busy (another program has it?) or no pixel format OpenCV reads"
        raise BackendError(f"camera {self._name}: cannot open it with cv2.VideoCapture "
                           f"(V4L2): {why}")

    def _open_stream(self) -> Any:
        import cv2

        params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, round(self._open_timeout_s * 1000),
                  cv2.CAP_PROP_READ_TIMEOUT_MSEC, round(self._read_timeout_s * 1000)]
        why = ""
        for _ in range(2):
            cap = self._new_capture(str(self._source), cv2.CAP_FFMPEG, params)
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

    def _start(self, fps: float | None) -> tuple[int, int]:
        """Settings (a device), the stream reader (a URL); the picture's size."""
        import cv2

        if self._kind == "device":
            self._read_back, self._refused = configure(self._cap, self._settings, self._name)
            w, h = self._read_back["width"], self._read_back["height"]
        else:
            if self._settings.asked():
                log.warning("camera %s: camera_settings ignored: a video file has no device "
                            "settings", self._name)
            w = int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH))
            h = int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
            reported = float(self._cap.get(cv2.CAP_PROP_FPS) or 0.0)
            self._read_back = {"width": w, "height": h,
                               "fps": fps if fps is not None else round(reported, 3)}
        if self._url:
            self._reader = StreamReader(self._cap, self._open_stream, str(self._source),
                                        self._read_timeout_s, fixed_fps=fps)
        if w <= 0 or h <= 0:
            frame = self.read()
            h, w = frame.shape[:2]
        return (w, h)

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

    # -- reading -----------------------------------------------------------------------
    @property
    def size(self) -> tuple[int, int]:
        return self._size

    def read(self) -> npt.NDArray[np.uint8]:
        """A BGR frame taken after this call started (a stream, a device), or the file's
        next frame."""
        if self._reader is not None:
            ok, frame = self._reader.fresh_frame(self._read_timeout_s)
            self.drained = self._reader.skipped
            if not ok and self._reader.frozen_s >= FROZEN_S:
                raise BackendError(f"camera {self._name!r} is frozen: its frames have been "
                                   f"identical for {self._reader.frozen_s:.1f} s (a camera "
                                   "whose picture stopped updating; restart it)")
        elif self._kind == "device":
            ok, frame = self._read_device()
        else:
            ok, frame = self._read_file()
        if not ok or frame is None or frame.ndim != 3 or frame.shape[2] != 3:
            what = f" within {self._read_timeout_s:g} s" if self._kind != "file" else ""
            shown = self._name if self._node is not None else repr(self._name)
            raise BackendError(f"camera {shown} gave no frame{what}")
        return np.ascontiguousarray(frame, dtype=np.uint8)

    def _read_file(self) -> tuple[bool, Any]:
        for _ in range(self._flush or 0):
            self._cap.grab()
        ok, frame = self._cap.read()
        if not ok:  # at the end of the file: start it again
            self._cap.release()
            self._cap = self._new_capture(self._source)
            ok, frame = self._cap.read()
        return ok, frame

    def _buffers(self) -> int:
        n = int(self._read_back.get("buffers") or 0)
        return n if n > 0 else DEFAULT_BUFFERS

    def _read_device(self) -> tuple[bool, Any]:
        """The first frame stamped at or after the call; by count when stamps are off
        (module docstring). Only the answer is decoded (``retrieve``)."""
        import cv2

        t0 = time.monotonic()
        count = self._buffers() + 1
        if self._flush is not None:
            return self._grab_then_retrieve(self._flush + 1, 0)
        if not self._use_stamps:
            return self._grab_then_retrieve(count, 0)
        stamp, n = 0.0, 0
        for n in range(1, count + STRADDLE_FRAMES + 1):
            if not self._cap.grab():
                return False, None
            stamp = float(self._cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0
            if not 0.0 < stamp <= time.monotonic() + CLOCK_SLACK_S:
                self._stop_stamps(stamp, "none or from another clock")
                return self._grab_then_retrieve(count, n)
            if stamp >= t0:
                return self._grab_then_retrieve(n, n)
        self._stop_stamps(stamp, f"still {t0 - stamp:.3f} s before the call after {n} frames")
        return self._grab_then_retrieve(n, n)

    def _grab_then_retrieve(self, total: int, grabbed: int) -> tuple[bool, Any]:
        """Grab up to ``total`` frames in all (``grabbed`` already), decode the last."""
        for _ in range(grabbed, total):
            if not self._cap.grab():
                return False, None
        self.drained = max(total, grabbed) - 1
        return self._cap.retrieve()

    def _stop_stamps(self, stamp: float, why: str) -> None:
        self._use_stamps = False
        log.info("camera %s: its frame timestamps are not this host's monotonic clock "
                 "(%s; stamp %.3f s, now %.3f s): every read now drains %d frames",
                 self._name, why, stamp, time.monotonic(), self._buffers() + 1)

    # -- what the camera says of itself --------------------------------------------------
    def settings(self) -> dict[str, Any]:
        """What the camera had when it opened: a device's settings as read back from it
        (the keys of ``camera_settings`` plus ``buffers``); a stream's or a file's size
        and reported rate. What ``testbed check`` prints."""
        return dict(self._read_back)

    def describe(self) -> dict[str, Any]:
        """Source, kind, size, settings read back; for a device also its node, card name,
        kind, stable links, the settings asked and the ones it did not take, and how a
        read is kept fresh."""
        out: dict[str, Any] = {"source": str(self._source), "kind": self._kind,
                               "size": list(self._size), "settings": self.settings()}
        if self._url:
            out["fresh"] = "stream reader thread: first frame waited for after the call"
        node = self._node
        if node is not None:
            fresh = (f"fixed flush of {self._flush}" if self._flush is not None else
                     "frame timestamps: first frame exposed after the call"
                     if self._use_stamps else f"count: {self._buffers() + 1} grabs per read")
            out.update(node=node.path, card=node.card, node_kind=node.kind,
                       links=self._devices.links(node), asked=self._settings.asked(),
                       refused=dict(self._refused), fresh=fresh)
        return out

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

    Only this thread touches the ``cv2.VideoCapture`` (it is not thread-safe): it grabs
    and retrieves (colour conversion) every frame, so that a camera whose frames stopped
    changing (:mod:`drivers.cameras.frozen_frames`) fails the request instead of answering
    with a picture of the past. A broken stream is reopened once (a restarted camera);
    then every request fails.
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
        self._watch = FrozenWatch()
        self.frozen_s = 0.0
        """How long the frames had been identical when the last request was answered
        (at least ``FROZEN_S``: the request failed, the camera is frozen)."""
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
                    self._watch.reset()
                    continue
                waited = now - t > 0.5 * self._interval()
                if waited and self._last_arrival is not None:
                    self._intervals = [*self._intervals[-15:], now - self._last_arrival]
                self._last_arrival = now
                result = self._cap.retrieve()  # every frame: a frozen camera is seen
                if result[0] and result[1] is not None:
                    self._watch.feed(result[1], now)
                with self._cond:
                    want = self._want_after
                if want is None:
                    continue
                if t >= want and waited:
                    with self._cond:
                        self.frozen_s = self._watch.frozen_for(now)
                        self._result = (False, None) if self._watch.frozen(now) else result
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
            self.frozen_s = 0.0
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
