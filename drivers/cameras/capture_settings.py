"""A V4L2 camera's picture settings: asked of the device through OpenCV, and read back.

Why: perception thresholds colours, so an exposure, a white balance or a focus that the
camera changes on its own (with the daylight, or when a pusher or a hand is in view)
changes what perception sees; and the crops and the calibration are pixels of one
resolution. A lab fixes them in the host's config (``camera_settings``). A device may
refuse a setting or quietly take another value (V4L2 clamps a control into its range and
picks the nearest size and rate it has), so every setting is read back after all are
set, the pair is logged, and each setting the device did not take is one warning line
naming it, asked vs got. A setting left out is left as the device has it: V4L2 keeps a
control's value between programs, so "auto" is a value here (automatic mode back on).

The order matters: the pixel format first (the sizes a device offers depend on it), then
the size (OpenCV restarts the stream for each), the rate, and for exposure, white
balance and focus the automatic mode off before the manual value (a device ignores or
refuses a manual value while its automatic mode is on).

OpenCV's V4L2 backend passes the device's own units: exposure in
``exposure_time_absolute`` units (100 us on UVC), white balance in kelvin, focus in the
device's ``focus_absolute`` steps; ``CAP_PROP_AUTO_EXPOSURE`` is V4L2's menu (1 manual, 3
aperture priority, UVC's automatic). ``CAP_PROP_MODE = 0`` is set first so these stay raw
even where ``OPENCV_VIDEOIO_V4L_RANGE_NORMALIZED`` is set.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

from drivers.cameras.v4l2_devices import fourcc_text
from drivers.errors import BackendError

AUTO = "auto"
EXPOSURE_MANUAL = 1
EXPOSURE_AUTO_MODES = (3, 0)
"""V4L2 ``exposure_auto`` values tried for "auto": aperture priority (UVC), then auto."""
FPS_TOLERANCE = 0.01
"""A read-back rate within 1 % of the asked one counts as taken (30 vs 29.97)."""

log = logging.getLogger(__name__)
log.setLevel(logging.INFO)
"""One INFO line per camera opened (asked vs read back) belongs in the host log, whose
agent logs others' records from WARNING up (``drivers/agent.py``)."""

_INT_FIELDS = {"width": (16, 16384), "height": (16, 16384), "fps": (1, 1000)}
_AUTO_FIELDS = {"exposure": (1, 1_000_000), "white_balance": (1000, 15000),
                "focus": (0, 100_000)}


@dataclass(frozen=True, slots=True)
class CaptureSettings:
    """What a host's config asks of its camera; None: leave it as the device has it."""

    width: int | None = None
    height: int | None = None
    fourcc: str | None = None
    """Four characters (``"MJPG"``, ``"YUYV"``); a shorter one is padded with spaces."""
    fps: int | None = None
    exposure: int | str | None = None
    """Manual exposure in the device's units, or "auto"."""
    white_balance: int | str | None = None
    """Manual white balance in kelvin, or "auto"."""
    focus: int | str | None = None
    """Manual focus position (autofocus off), or "auto"."""

    @classmethod
    def parse(cls, value: CaptureSettings | Mapping[str, Any] | str | None
              ) -> CaptureSettings:
        """From the agent's ``--camera-settings`` JSON, a mapping or None; a bad one is a
        one-line :class:`BackendError` naming the key (the config checked it already,
        this guards an agent started by hand)."""
        if isinstance(value, CaptureSettings):
            return value
        if value is None:
            return cls()
        if isinstance(value, str):
            try:
                value = json.loads(value)
            except ValueError as exc:
                raise BackendError(f"camera_settings: not JSON: {exc}") from None
        if not isinstance(value, Mapping):
            raise BackendError("camera_settings: must be an object of width, height, "
                               "fourcc, fps, exposure, white_balance, focus")
        known = set(_INT_FIELDS) | set(_AUTO_FIELDS) | {"fourcc"}
        if extra := sorted(set(value) - known):
            raise BackendError(f"camera_settings: unknown key(s) {extra}; known: "
                               f"{sorted(known)}")
        out = {k: _checked(k, v) for k, v in value.items() if v is not None}
        if ("width" in out) != ("height" in out):
            raise BackendError("camera_settings: give width and height together")
        return cls(**out)

    def asked(self) -> dict[str, Any]:
        """The settings given (None ones left out)."""
        return {k: v for k, v in asdict(self).items() if v is not None}


def _checked(key: str, v: Any) -> Any:
    if key == "fourcc":
        if not isinstance(v, str) or not 1 <= len(v) <= 4 or not v.isascii() \
                or not v.strip().isalnum():
            raise BackendError(f"camera_settings.fourcc: 1 to 4 letters or digits, got {v!r}")
        return v.ljust(4)
    if key in _AUTO_FIELDS and v == AUTO:
        return v
    lo, hi = {**_INT_FIELDS, **_AUTO_FIELDS}[key]
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        also = ' or "auto"' if key in _AUTO_FIELDS else ""
        raise BackendError(f"camera_settings.{key}: a whole number in [{lo}, {hi}]{also}, "
                           f"got {v!r}")
    return v


def _props() -> dict[str, int]:
    import cv2

    return {"mode": cv2.CAP_PROP_MODE, "width": cv2.CAP_PROP_FRAME_WIDTH,
            "height": cv2.CAP_PROP_FRAME_HEIGHT, "fourcc": cv2.CAP_PROP_FOURCC,
            "fps": cv2.CAP_PROP_FPS, "auto_exposure": cv2.CAP_PROP_AUTO_EXPOSURE,
            "exposure": cv2.CAP_PROP_EXPOSURE, "auto_wb": cv2.CAP_PROP_AUTO_WB,
            "wb_temperature": cv2.CAP_PROP_WB_TEMPERATURE,
            "autofocus": cv2.CAP_PROP_AUTOFOCUS, "focus": cv2.CAP_PROP_FOCUS,
            "buffers": cv2.CAP_PROP_BUFFERSIZE}


_CONTROLS = {"exposure": ("auto_exposure", "exposure"),
             "white_balance": ("auto_wb", "wb_temperature"),
             "focus": ("autofocus", "focus")}
"""Each control setting: its automatic-mode property and its value property."""


def _set_control(cap: Any, key: str, value: int | str) -> None:
    """Automatic mode off then the value, or automatic mode on ("auto")."""
    p = _props()
    auto, prop = _CONTROLS[key]
    if key == "exposure":
        if value == AUTO:
            for mode in EXPOSURE_AUTO_MODES:
                if cap.set(p[auto], mode):
                    return
            return
        cap.set(p[auto], EXPOSURE_MANUAL)
    else:
        cap.set(p[auto], 1 if value == AUTO else 0)
        if value == AUTO:
            return
    cap.set(p[prop], float(value))


def apply_settings(cap: Any, settings: CaptureSettings) -> None:
    """Ask the device for ``settings`` in the order of the module docstring (no reads)."""
    p = _props()
    cap.set(p["mode"], 0)  # raw device units, whatever the environment says
    if settings.fourcc is not None:
        import cv2

        cap.set(p["fourcc"], cv2.VideoWriter.fourcc(*settings.fourcc))
    if settings.width is not None and settings.height is not None:
        cap.set(p["width"], settings.width)
        cap.set(p["height"], settings.height)
    if settings.fps is not None:
        cap.set(p["fps"], settings.fps)
    for key in ("exposure", "white_balance", "focus"):
        value = getattr(settings, key)
        if value is not None:
            _set_control(cap, key, value)


def _control(cap: Any, key: str) -> int | str | None:
    """A control as read back: its value when manual, "auto" when its automatic mode is
    on, None when the device has no such control (OpenCV reads -1)."""
    p = _props()
    auto_name, value_name = _CONTROLS[key]
    auto = float(cap.get(p[auto_name]))
    value = float(cap.get(p[value_name]))
    manual = EXPOSURE_MANUAL if key == "exposure" else 0
    if auto >= 0 and round(auto) != manual:
        return AUTO
    if value < 0:  # none of these is negative: -1 is OpenCV's "no such control"
        return None
    return round(value)


def read_settings(cap: Any) -> dict[str, Any]:
    """What the device has now, in the keys of :class:`CaptureSettings`, plus ``buffers``
    (its driver queue, OpenCV's ``CAP_PROP_BUFFERSIZE``)."""
    p = _props()
    fps = float(cap.get(p["fps"]))
    out: dict[str, Any] = {
        "width": int(cap.get(p["width"])), "height": int(cap.get(p["height"])),
        "fourcc": fourcc_text(int(cap.get(p["fourcc"]))),
        "fps": round(fps, 3) if math.isfinite(fps) and fps > 0 else None}
    for key in _CONTROLS:
        out[key] = _control(cap, key)
    out["buffers"] = int(cap.get(p["buffers"]))
    return out


def _taken(key: str, asked: Any, got: Any) -> bool:
    if key == "fps" and isinstance(got, float):
        return abs(got - asked) <= FPS_TOLERANCE * asked
    return bool(got == asked)


def _shown(key: str, v: Any) -> str:
    if v is None:
        return "nothing (the device has no such control)"
    if v == AUTO:
        return "auto"
    if key == "fourcc":
        return repr(v.strip())
    return f"manual {v}" if key in _CONTROLS else str(v)


def configure(cap: Any, settings: CaptureSettings, name: str) -> tuple[dict[str, Any],
                                                                       dict[str, str]]:
    """Set, read back, log: (what the device has, {setting: "asked X, got Y"} for each one
    it did not take). One INFO line with both; one WARNING line per setting not taken."""
    asked = settings.asked()
    if asked:
        apply_settings(cap, settings)
    got = read_settings(cap)
    refused = {k: f"asked {_shown(k, v)}, got {_shown(k, got.get(k))}"
               for k, v in asked.items() if not _taken(k, v, got.get(k))}
    log.info("camera %s: settings asked %s; read back %s", name,
             json.dumps(asked) if asked else "none", json.dumps(got))
    for key, what in refused.items():
        log.warning("camera %s: the device did not take %s: %s", name, key, what)
    return got, refused
