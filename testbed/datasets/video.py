"""MP4 video of a dataset's images (``--images video``): the codec, writing, probing, decoding.

Why apart: the codec is a choice of its own, measured by ``benchmarks/bench_export.py``
and argued in docs/notes/data.md: H.264 4:4:4 at CRF 18, a keyframe every 2 frames
(4:2:0 loses the 3-pixel goal marker of a 64x64 image). A file holds one run of frames,
frame k at pts k / fps; which episode is which frames is ``testbed.datasets.lerobot``'s.
Needs PyAV (the ``export`` extra).
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, Final

import av
import numpy as np

from testbed.core.config import ConfigError
from testbed.datasets.episodes import IMAGE_SHAPE


@dataclass(frozen=True)
class VideoCodec:
    """An encoder and its settings (the default: ``--images video``'s)."""

    name: str = "libx264"
    pix_fmt: str = "yuv444p"
    crf: int = 18
    g: int = 2
    """Keyframe interval: LeRobot's default, so a random frame decodes from <= 1 other."""
    extra: tuple[tuple[str, str], ...] = ()
    """Codec-specific options (e.g. SVT-AV1's ``preset``)."""

    def options(self) -> dict[str, str]:
        return {"crf": str(self.crf), "g": str(self.g), **dict(self.extra)}


VIDEO: Final = VideoCodec()


def check_codec(codec: VideoCodec = VIDEO) -> None:
    """ConfigError, in one line, if this PyAV cannot encode with ``codec``."""
    try:
        av.codec.Codec(codec.name, "w")
    except Exception:  # PyAV's UnknownCodecError and friends
        raise ConfigError(f"--images video: this PyAV has no {codec.name} encoder; use "
                          "--images png") from None


class VideoFile:
    """One MP4 file being written: frame k at pts k (time base 1/fps)."""

    def __init__(self, path: Path, fps: int, codec: VideoCodec) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.fps = fps
        self._out = av.open(str(path), "w")
        self._stream = self._out.add_stream(codec.name, rate=fps, options=codec.options())
        self._stream.width = IMAGE_SHAPE[1]
        self._stream.height = IMAGE_SHAPE[0]
        self._stream.pix_fmt = codec.pix_fmt
        self.frames = 0
        self.bytes = 0
        """Bytes of the packets muxed so far (the file on disk lags behind its buffer)."""

    def add(self, images: np.ndarray) -> None:
        for img in images:
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
            frame.pts = self.frames
            frame.time_base = Fraction(1, self.fps)
            self._mux(self._stream.encode(frame))
            self.frames += 1

    def _mux(self, packets: list[av.Packet]) -> None:
        for packet in packets:
            self.bytes += packet.size
            self._out.mux(packet)

    def close(self) -> None:
        self._mux(self._stream.encode())
        self._out.close()


def video_info(path: Path, codec: VideoCodec = VIDEO) -> dict[str, Any]:
    """A video feature's ``info``, probed from the file as LeRobot's get_video_info."""
    with av.open(str(path)) as c:
        s = c.streams.video[0]
        info: dict[str, Any] = {
            "video.height": s.height, "video.width": s.width,
            "video.codec": s.codec_context.codec.canonical_name, "video.pix_fmt": s.pix_fmt,
            "video.is_depth_map": False, "video.fps": int(s.base_rate or 0),
            "video.channels": 3, "has_audio": bool(c.streams.audio)}
    info.update({"video.g": codec.g, "video.crf": codec.crf, "is_depth_map": False})
    return info


def decode_video(path: Path, fps: int) -> np.ndarray:
    """Every frame of an MP4, at its position pts * time_base * fps."""
    with av.open(str(path)) as c:
        s = c.streams.video[0]
        got = [(round(float(f.pts * f.time_base) * fps), f.to_ndarray(format="rgb24"))
               for f in c.decode(s)]
    out = np.zeros((max((k for k, _ in got), default=-1) + 1, *IMAGE_SHAPE), np.uint8)
    for k, img in got:
        out[k] = img
    return out
