"""A V4L2 camera stood in AT THE cv2.VideoCapture SEAM, and a fake /dev and sysfs.

Why a fake at that seam: a kernel camera device cannot exist on a CI machine (no
``/dev/videoN``, no ``/sys/class/video4linux``), and what the camera code must get right
is what OpenCV's V4L2 backend does with a device's queue and controls
(``modules/videoio/src/cap_v4l.cpp``):

- ``CAP_PROP_BUFFERSIZE`` driver buffers (4 by default), all queued when streaming
  starts (the first ``grab``, which also skips the stream's first frame). The device
  takes a frame every 1/fps; a frame goes into a free buffer as it starts (its
  ``CAP_PROP_POS_MSEC`` is that moment: UVC stamps the start of exposure on
  CLOCK_MONOTONIC) and can be dequeued one frame interval later (readout and transfer);
  with no free buffer the frame is dropped. ``grab()`` requeues the buffer it held and
  dequeues the oldest done one (waiting for one if none is done, up to
  ``OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT`` seconds, as OpenCV's select); ``retrieve()``
  decodes the held buffer and requeues it; ``read()`` is both.
- ``set``/``get`` as the backend: width and height change the size once both are set
  (the nearest mode the device has), the pixel format only if the device has it (else
  False), the rate to the nearest it has, controls clamped into their range and rounded
  to their step, a menu value it lacks refused, a manual value refused while its
  automatic mode is on, a control the device lacks refused and read as -1.

Every frame carries its number (``mjpeg_fixture.stamp``) and ``FakeDevice.taken[n]`` is
when frame n was taken, so a test can tell how old a picture is.
"""

from __future__ import annotations

import os
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from mjpeg_fixture import stamp

Stamps = Literal["monotonic", "none", "realtime", "relative"]


@dataclass
class Control:
    """One V4L2 control: its range and step, a menu's values, the automatic mode that
    must be off (``manual_when``: (property, value)) before a value is accepted."""

    lo: int
    hi: int
    value: int
    step: int = 1
    menu: tuple[int, ...] | None = None
    manual_when: tuple[int, int] | None = None


def uvc_controls(*, focus: bool = True, wb_range: tuple[int, int] = (2800, 6500)
                 ) -> dict[int, Control]:
    """A typical UVC webcam's controls, everything automatic (as it powers up)."""
    out = {
        cv2.CAP_PROP_AUTO_EXPOSURE: Control(0, 3, 3, menu=(1, 3)),
        cv2.CAP_PROP_EXPOSURE: Control(3, 2047, 250,
                                       manual_when=(cv2.CAP_PROP_AUTO_EXPOSURE, 1)),
        cv2.CAP_PROP_AUTO_WB: Control(0, 1, 1),
        cv2.CAP_PROP_WB_TEMPERATURE: Control(*wb_range, 4000, step=10,
                                             manual_when=(cv2.CAP_PROP_AUTO_WB, 0)),
    }
    if focus:
        out[cv2.CAP_PROP_AUTOFOCUS] = Control(0, 1, 1)
        out[cv2.CAP_PROP_FOCUS] = Control(0, 250, 30, step=5,
                                          manual_when=(cv2.CAP_PROP_AUTOFOCUS, 0))
    return out


@dataclass
class FakeDevice:
    """What the camera is. ``capture`` is the factory handed to VideoCaptureCamera."""

    modes: tuple[tuple[int, int], ...] = ((640, 480), (1280, 720), (1920, 1080))
    formats: tuple[str, ...] = ("YUYV", "MJPG")
    rates: tuple[int, ...] = (30, 15, 5)
    controls: dict[int, Control] = field(default_factory=uvc_controls)
    stamps: Stamps = "monotonic"
    stalled: bool = False
    """No more frames (a camera that stops sending)."""
    taken: dict[int, float] = field(default_factory=dict)
    """Frame number -> when it was taken (time.monotonic(), start of exposure)."""
    opens: list[tuple[Any, ...]] = field(default_factory=list)
    """The arguments of every capture built (``(index, cv2.CAP_V4L2)``)."""
    captures: list[FakeCapture] = field(default_factory=list)
    count: int = 0

    def capture(self, *args: Any) -> FakeCapture:
        """The constructor seam: ``cv2.VideoCapture(index, cv2.CAP_V4L2)`` for this device."""
        self.opens.append(args)
        self.captures.append(FakeCapture(self))
        return self.captures[-1]


@dataclass
class _Frame:
    number: int
    taken: float
    ready: float


class FakeCapture:
    """``cv2.VideoCapture`` on a :class:`FakeDevice` (module docstring)."""

    def __init__(self, device: FakeDevice) -> None:
        self.device = device
        self.width, self.height = device.modes[0]
        self.fourcc = device.formats[0]
        self.fps = device.rates[0]
        self.buffers = 4
        self.normalized = False
        self.grabs = 0
        self.decoded = 0
        self.dropped = 0
        self._open = True
        self._asked_size = [0, 0]
        self._streaming = False
        self._start = 0.0
        self._next = 0
        self._free = 0
        self._done: deque[_Frame] = deque()
        self._held: _Frame | None = None
        self._last: _Frame | None = None

    # -- the device's clock ------------------------------------------------------------
    def _advance(self, now: float) -> None:
        """Every frame started by ``now`` goes into a free buffer, or is dropped."""
        while self._streaming and not self.device.stalled:
            t = self._start + (self._next + 1) / self.fps
            if t > now:
                return
            self._next += 1
            if self._free == 0:
                self.dropped += 1
                continue
            self._free -= 1
            n = self.device.count
            self.device.count += 1
            self.device.taken[n] = t
            self._done.append(_Frame(n, t, t + 1.0 / self.fps))

    def _stream_on(self) -> None:
        self._streaming = True
        self._start = time.monotonic()
        self._next = 0
        self._free = self.buffers
        self._done.clear()
        self._held = None

    def _stream_off(self) -> None:
        self._streaming = False
        self._done.clear()
        self._held = None

    def _dequeue(self) -> bool:
        deadline = time.monotonic() + float(os.environ.get(
            "OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT", "10"))
        while True:
            now = time.monotonic()
            self._advance(now)
            if self._done and self._done[0].ready <= now:
                self._held = self._last = self._done.popleft()
                return True
            if now >= deadline:
                return False
            nxt = self._done[0].ready if self._done else (
                self._start + (self._next + 2) / self.fps)
            time.sleep(min(max(nxt - now, 0.0005), deadline - now))

    def _requeue(self) -> None:
        if self._held is not None:
            self._advance(time.monotonic())  # frames up to now saw the old queue
            self._free += 1
            self._held = None

    # -- cv2.VideoCapture ----------------------------------------------------------------
    def isOpened(self) -> bool:  # OpenCV's name
        return self._open

    def getBackendName(self) -> str:
        return "V4L2"

    def release(self) -> None:
        self._open = False
        self._stream_off()

    def grab(self) -> bool:
        if not self._open:
            return False
        self.grabs += 1
        if not self._streaming:
            self._stream_on()
            if not self._dequeue():  # OpenCV skips the stream's first frame
                return False
        self._requeue()
        return self._dequeue()

    def retrieve(self) -> tuple[bool, np.ndarray | None]:
        if self._held is None:
            return False, None
        self.decoded += 1
        img = stamp(self._held.number, (self.width, self.height))
        self._requeue()
        return True, img

    def read(self) -> tuple[bool, np.ndarray | None]:
        return self.retrieve() if self.grab() else (False, None)

    def get(self, prop: int) -> float:
        d = self.device
        simple = {cv2.CAP_PROP_FRAME_WIDTH: self.width, cv2.CAP_PROP_FRAME_HEIGHT: self.height,
                  cv2.CAP_PROP_FOURCC: cv2.VideoWriter.fourcc(*self.fourcc),
                  cv2.CAP_PROP_FPS: self.fps, cv2.CAP_PROP_BUFFERSIZE: self.buffers,
                  cv2.CAP_PROP_MODE: int(self.normalized), cv2.CAP_PROP_BACKEND: cv2.CAP_V4L2}
        if prop in simple:
            return float(simple[prop])
        if prop == cv2.CAP_PROP_POS_MSEC:
            return self._stamp_ms()
        return float(d.controls[prop].value) if prop in d.controls else -1.0

    def _stamp_ms(self) -> float:
        if self._last is None:
            return 0.0
        t = self._last.taken
        return {"monotonic": t * 1000.0, "none": 0.0,
                "realtime": (t + time.time() - time.monotonic()) * 1000.0,
                "relative": (t - self._start) * 1000.0}[self.device.stamps]

    def set(self, prop: int, value: float) -> bool:
        v = round(value)
        if prop in (cv2.CAP_PROP_FRAME_WIDTH, cv2.CAP_PROP_FRAME_HEIGHT):
            self._asked_size[prop == cv2.CAP_PROP_FRAME_HEIGHT] = v
            if 0 in self._asked_size:
                return True
            w, h = self._asked_size
            self._asked_size = [0, 0]
            self.width, self.height = min(self.device.modes,
                                          key=lambda m: abs(m[0] - w) + abs(m[1] - h))
            self._stream_off()
            return True
        if prop == cv2.CAP_PROP_FOURCC:
            text = bytes((v >> (8 * i)) & 0xFF for i in range(4)).decode("latin-1")
            if text not in self.device.formats:
                return False
            self.fourcc = text
            self._stream_off()
            return True
        if prop == cv2.CAP_PROP_FPS:
            self.fps = min(self.device.rates, key=lambda r: abs(r - v))
            return True
        if prop == cv2.CAP_PROP_BUFFERSIZE:
            if not 1 <= v <= 10:
                return False
            self.buffers = v
            self._stream_off()
            return True
        if prop == cv2.CAP_PROP_MODE:
            self.normalized = bool(v)
            return True
        return self._set_control(prop, v)

    def _set_control(self, prop: int, v: int) -> bool:
        c = self.device.controls.get(prop)
        if c is None:
            return False  # no such control
        if c.menu is not None and v not in c.menu:
            return False
        if c.manual_when is not None:
            auto, manual = c.manual_when
            if self.device.controls[auto].value != manual:
                return False  # the automatic mode is on: a manual value is refused
        v = min(max(v, c.lo), c.hi)
        c.value = c.lo + round((v - c.lo) / c.step) * c.step
        return True


# --- a fake /dev and /sys/class/video4linux ---------------------------------------------
@dataclass
class FakeNode:
    number: int
    card: str
    index: int
    usb: str
    """The USB device (e.g. "1-2"): nodes with one are one physical camera."""
    interface: int = 0


def fake_tree(root: Path, nodes: list[FakeNode]) -> tuple[Path, Path]:
    """``root/dev/videoN`` (plain files) and ``root/sys/class/video4linux/videoN/{name,
    index,device}`` as the kernel lays them out (``device`` -> the USB interface)."""
    dev = root / "dev"
    sysfs = root / "sys" / "class" / "video4linux"
    dev.mkdir(parents=True, exist_ok=True)
    sysfs.mkdir(parents=True, exist_ok=True)
    for n in nodes:
        (dev / f"video{n.number}").write_bytes(b"")
        d = sysfs / f"video{n.number}"
        d.mkdir()
        (d / "name").write_text(n.card + "\n")
        (d / "index").write_text(f"{n.index}\n")
        iface = root / "sys" / "devices" / "usb1" / n.usb / f"{n.usb}:1.{n.interface}"
        iface.mkdir(parents=True, exist_ok=True)
        (d / "device").symlink_to(iface)
    return dev, sysfs


def link(dev: Path, kind: str, name: str, number: int) -> Path:
    """``dev/v4l/<kind>/<name>`` -> ``../../videoN``, as udev makes it."""
    folder = dev / "v4l" / kind
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.symlink_to(f"../../video{number}")
    return path
