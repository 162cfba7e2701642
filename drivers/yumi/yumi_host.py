"""A YuMi host's config: the fields the YuMi backend adds to every host's.

Why here: a backend's schema lives with the backend (``testbed.core.host_config`` holds
what every host has); the YuMi plugin (``yumi_plugin.py``) declares this model as its
hosts', and the agent's flags are written from it there. Everything the agent needs is
checked at load time, so a typo is one line before anything starts.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal
from urllib.parse import urlsplit

from pydantic import (
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationInfo,
    field_validator,
    model_validator,
)
from typing_extensions import Self

from testbed.core.config import FieldProblem, StrictModel, expand_path
from testbed.core.host_config import HostBase

__all__ = ["CAMERA_AUTO", "CAMERA_SCHEMES", "CONTROLLER_SCHEMES", "CameraSettings", "YumiHost"]

CONTROLLER_SCHEMES = ("http", "https")
CAMERA_SCHEMES = ("http", "https", "rtsp")


def _camera_text(value: Any) -> Any:
    """TOML ``camera = 0`` (an integer) means device 0, as ``camera = "0"``."""
    return str(value) if isinstance(value, int) and not isinstance(value, bool) else value


CAMERA_AUTO = "auto"
_CAMERA_CONTROLS: dict[str, tuple[int, int, str]] = {
    "exposure": (1, 1_000_000, "manual exposure in the device's units, 100 us on UVC"),
    "white_balance": (1000, 15000, "manual white balance in kelvin"),
    "focus": (0, 100_000, "manual focus position, autofocus off"),
}


class CameraSettings(StrictModel):
    """A V4L2 camera's picture (a YuMi host's ``camera_settings`` table).

    Why: perception thresholds colours, so exposure, white balance and focus must not
    drift with the daylight or with what is in view, and the crops and calibration are
    pixels of one resolution. A field left out is left as the device has it (V4L2 keeps
    a control between programs: ``"auto"`` turns the automatic mode back on). The agent
    sets them when it opens the camera, reads each back and warns once per setting the
    device did not take, asked vs got (``drivers/cameras/capture_settings.py``).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    width: int | None = Field(None, ge=16, le=16384)
    height: int | None = Field(None, ge=16, le=16384)
    fourcc: str | None = None
    """Pixel format, 1 to 4 letters or digits (``"MJPG"``, ``"YUYV"``; padded with spaces)."""
    fps: int | None = Field(None, ge=1, le=1000)
    exposure: int | Literal["auto"] | None = None
    """Manual exposure (auto exposure off) in the device's units, or ``"auto"``."""
    white_balance: int | Literal["auto"] | None = None
    """Manual white balance in kelvin (auto white balance off), or ``"auto"``."""
    focus: int | Literal["auto"] | None = None
    """Manual focus position (autofocus off), or ``"auto"``."""

    @field_validator("fourcc", mode="before")
    @classmethod
    def _fourcc(cls, v: Any) -> Any:
        if v is None:
            return v
        if not isinstance(v, str) or not 1 <= len(v) <= 4 or not v.isascii() \
                or not v.strip().isalnum():
            raise ValueError('a pixel format of 1 to 4 letters or digits, e.g. "MJPG" or '
                             '"YUYV"')
        return v.ljust(4)

    @field_validator("exposure", "white_balance", "focus", mode="before")
    @classmethod
    def _manual_or_auto(cls, v: Any, info: ValidationInfo) -> Any:
        lo, hi, what = _CAMERA_CONTROLS[str(info.field_name)]
        if v is None or v == CAMERA_AUTO:
            return v
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise ValueError(f'a whole number in [{lo}, {hi}] ({what}) or "auto"')
        return v

    @model_validator(mode="after")
    def _size_is_a_pair(self) -> Self:
        if (self.width is None) != (self.height is None):
            missing = "height" if self.height is None else "width"
            raise FieldProblem(missing, "give width and height together (the device is "
                               "asked for one size), or neither")
        return self


class YumiHost(HostBase):
    """An ABB YuMi (IRB 14000) with an overhead camera (``drivers/yumi/backend.py``).

    Everything the agent needs is checked here, at load time, so a typo is one line
    before anything starts rather than a traceback on the host after pretraining.
    """

    backend: Literal["yumi"] = "yumi"
    camera: Annotated[str, BeforeValidator(_camera_text)]
    """A device index ("0"), a video file path, or a lab IP camera URL (http(s), rtsp)."""
    camera_settings: CameraSettings | None = None
    """The V4L2 camera's resolution, pixel format, rate, exposure, white balance and
    focus (TOML ``[hosts.camera_settings]``); None: left as the device has them. Not for
    a URL camera (set a network camera's picture on the camera)."""
    controller_url: str
    """The controller's Robot Web Services: http(s)://HOST[:PORT] (a lab's IRC5, or the
    hardware twin's RWS in a rehearsal)."""
    credentials_file: str | None = None
    """A file ON THE HOST holding the controller's login, one line ``USER:PASSWORD``, mode
    0600 (``drivers/yumi/credentials.py``); never the password itself. Required to drive
    a controller: None loads (old configs keep loading) but the agent's controller client
    refuses it when it starts, in one line, and never falls back to ABB's factory login.
    ``"factory-default"`` names the factory login, which the driver takes only from a
    controller on loopback (the hardware twin; ``drivers/yumi/rws_controller.py``)."""
    deadline_s: float = Field(20.0, gt=0, le=600)
    """Per-call deadline for a push or an observation (a YuMi push is a motion of seconds)."""
    lock_dir: str | None = None
    """The folder of the robot locks ON THE HOST, shared by every user of the host
    (``drivers/hostlock.py``; default ``/run/lock/fleet-testbed``): one agent per robot,
    whoever starts it."""
    motion_timeout_s: float | None = Field(None, gt=0, le=600)
    """The longest one motion program may run before the agent stops it through RWS; below
    ``deadline_s``, so the controller hears why instead of a dead link. Default:
    ``min(15, 0.75 * deadline_s)``."""

    @field_validator("camera")
    @classmethod
    def _camera_kind(cls, v: str) -> str:
        v = v.strip()
        if not v:
            raise ValueError("camera is empty; give a device index, a video file or a URL")
        if "://" in v:
            url = urlsplit(v)
            if url.scheme not in CAMERA_SCHEMES or not url.netloc:
                raise ValueError(f"camera URL must be {', '.join(CAMERA_SCHEMES)}://HOST/...")
        return v

    @field_validator("controller_url")
    @classmethod
    def _controller_kind(cls, v: str) -> str:
        url = urlsplit(v.strip())
        if url.scheme not in CONTROLLER_SCHEMES or not url.hostname:
            raise ValueError("controller_url must be http(s)://HOST[:PORT] (the controller's "
                             "Robot Web Services)")
        return v.strip()

    @model_validator(mode="after")
    def _yumi_arms(self) -> Self:
        if self.motion_timeout_s is None:
            self._set("motion_timeout_s", min(15.0, 0.75 * self.deadline_s))
        elif self.motion_timeout_s >= self.deadline_s:
            raise FieldProblem("motion_timeout_s", f"{self.motion_timeout_s:g} s is not below "
                               f"deadline_s ({self.deadline_s:g} s): the agent must stop a "
                               "motion before the controller gives up on the host")
        if self.credentials_file is not None and not self.credentials_file.strip():
            raise FieldProblem("credentials_file", "is empty; name the host's USER:PASSWORD "
                               "file or leave the field out")
        for i, a in enumerate(self.arms):
            if a.crop is None:
                raise FieldProblem(f"arms[{i}].crop", f"arm {a.name} of a yumi host needs "
                                   "its crop box (x0, y0, x1, y1) in the camera image")
            if a.calibration is None or not a.calibration.endswith(".json"):
                raise FieldProblem(f"arms[{i}].calibration", f"arm {a.name} of a yumi host "
                                   "needs its calibration file (a path ending .json)")
        if self.transport == "local" and "://" not in self.camera and not self.camera.isdigit():
            self._set("camera", expand_path(self.camera, "camera"))
        if self.transport == "local" and self.credentials_file is not None:
            self._set("credentials_file", expand_path(self.credentials_file,
                                                      "credentials_file"))
        return self

    @model_validator(mode="after")
    def _camera_settings_need_a_device(self) -> Self:
        """A URL camera is read through FFmpeg, which sets nothing on the camera: settings
        there would be silently ignored, so they are an error naming the field."""
        if self.camera_settings is not None and "://" in self.camera:
            raise FieldProblem("camera_settings", "a network camera takes no settings from "
                               "here; set its picture on the camera itself, or remove "
                               "camera_settings")
        return self
