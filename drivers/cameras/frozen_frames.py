"""Telling a frozen camera from a live one: its frames stop changing, to the last bit.

Why it exists: a network camera whose encoder hangs goes on sending its last picture,
and the stream looks healthy (frames arrive at the frame rate, each decodes). A live
sensor's noise makes every frame differ from the one before it, so frames that stay
byte-identical for a while mean nobody is looking at the table any more: the backend
would judge pushes on a picture of the past (the rehearsal's ``camera_frozen`` fault,
issue 29). A camera that repeats a frame now and then (a sensor slower than its stream
in dim light) repeats it for a frame interval or two, never for :data:`FROZEN_S`.

Only a sample of the pixels is compared (every :data:`STRIDE`-th row and column): noise
shows in every pixel, so the sample differs between two live frames as surely as the
whole picture does, at a fraction of the cost.
"""

from __future__ import annotations

from typing import Any

FROZEN_S = 1.0
"""Frames identical for this long: the camera is frozen (a sensor at 1 fps or more never
repeats its picture for a second)."""
STRIDE = 8


class FrozenWatch:
    """Fed every frame of a stream with its arrival time; says since when the frames
    have been identical."""

    def __init__(self, frozen_s: float = FROZEN_S) -> None:
        self.frozen_s = frozen_s
        self._last: bytes | None = None
        self._same_since: float | None = None

    def feed(self, frame: Any, now: float) -> None:
        """One frame (an HxWx3 array) that arrived at ``now`` (``time.monotonic``)."""
        sample = frame[::STRIDE, ::STRIDE].tobytes()
        if sample != self._last:
            self._last, self._same_since = sample, now

    def reset(self) -> None:
        """The stream was reopened: nothing known."""
        self._last = self._same_since = None

    def frozen_for(self, now: float) -> float:
        """Seconds the frames have been identical (0: the last frame was new)."""
        return 0.0 if self._same_since is None else now - self._same_since

    def frozen(self, now: float) -> bool:
        return self.frozen_for(now) >= self.frozen_s
