"""The contract every host backend meets: the arms and the camera of ONE robot host.

Why an ABC (as LeRobot's ``Robot``): the agent, the conformance check and the tests talk
to a twin cell and to a real ABB YuMi through the same five calls, so a new robot is a
new subclass and nothing else changes. The backend works in the arms' *canonical*
frame (right-arm crops mirrored, ``testbed.core.types``); the agent puts its answers on the
wire unchanged.

Semantics (docs/ARCHITECTURE.md ``TwinCell``; the task constants in ``testbed.core.types``):

* ``observe`` takes ONE picture for all arms (the host's camera is shared) with every
  pusher out of view, and reports per arm the 64x64 canonical crop with the goal drawn
  in, whether the arm is violating (waiting for a hard reset) and the goal.
* ``push`` pushes all the named arms AT THE SAME TIME and reports each arm's outcome.
  A push on a violating arm is refused: no motion, outcome all False.
* ``reset`` completes a hard reset (twin: puts the cube back; physical: a human did it,
  the backend checks the picture) and says whether the arm is free again.
* ``rest`` moves every arm out of the camera's view; ``close`` releases the hardware.
* ``stop`` is the one call from another thread: the agent's reader calls it while a
  motion runs in its worker (the operator's stop, a lost link, the watchdog).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from testbed.core.types import IMAGE_SIZE, NUM_ACTIONS


@dataclass(frozen=True, slots=True)
class ArmView:
    """One arm's part of a host observation (what goes on the wire for that arm)."""

    image: npt.NDArray[np.uint8]
    """(64, 64, 3) uint8 RGB, canonical frame, goal drawn in."""
    violating: bool
    goal: tuple[float, float]
    expert_action: int | None = None
    png: bytes | None = None
    """The image already PNG-encoded, when the backend has it cached (saves an encode)."""


@dataclass(frozen=True, slots=True)
class ArmOutcome:
    """One arm's outcome of a push.

    ``refused``: the backend did not push this arm and says why (e.g. the cube was not
    found); the step is neither autonomous nor human for that arm. ``error``: this arm
    alone failed (its sibling's push still happened and is reported); the controller
    faults this arm only.

    ``readings``: what the host measured of this arm's push, by name (``"push_s"``: the
    push's duration on the host's clock), each a finite number. Why one generic mapping
    and not a field per value: a value only the host can measure then reaches the
    controller's ``PushResult`` and the arm's steps.jsonl row (``"readings"``) with no
    edit of the wire, the agent, the controller or the records: the backend that
    measures it is the one file to change (docs/ARCHITECTURE.md, "A new field in every
    step"). A name is a short identifier (``drivers.wire.MAX_READING_NAME`` characters
    at most), at most ``drivers.wire.MAX_READINGS`` of them; empty (the default) for a
    backend that measures nothing, as the twin, whose rows stay the same for one seed.
    """

    success: bool
    violation: bool
    refused: str | None = None
    error: str | None = None
    readings: Mapping[str, float] = field(default_factory=dict)


class HostBackend(ABC):
    """The arms and camera of one host. Not thread-safe: the agent calls it serially,
    from one worker thread, except :meth:`stop` (from the agent's reader thread)."""

    kind: str = "abstract"
    """Short backend name reported in the handshake ("twin", "yumi", ...)."""

    @property
    @abstractmethod
    def arm_names(self) -> tuple[str, ...]:
        """The host's arms, in config order."""

    @property
    def mirror(self) -> tuple[bool, ...]:
        """Per arm, whether its crop is mirrored into the canonical frame."""
        return tuple(False for _ in self.arm_names)

    @abstractmethod
    def observe(self) -> dict[str, ArmView]:
        """One picture for all arms; a view for every arm in ``arm_names``."""

    @abstractmethod
    def push(self, faces: Mapping[str, int]) -> dict[str, ArmOutcome]:
        """Push the named arms at the same time; an outcome for exactly those arms."""

    @abstractmethod
    def reset(self, arms: Sequence[str]) -> dict[str, bool]:
        """Complete the hard reset of ``arms``; per arm, True when it is free again."""

    @abstractmethod
    def rest(self) -> None:
        """Every arm to its rest pose, out of the camera's view."""

    @abstractmethod
    def close(self) -> None:
        """Release the hardware; idempotent."""

    def stop(self) -> None:
        """Stop any motion in progress NOW.

        Called from another thread than the one running ``push``/``reset``/``rest``/
        ``move_tcp``/``observe`` (the agent's reader: the operator pressed stop, the
        link was lost, or the watchdog heard nothing from the controller); it must
        return within 0.5 s, motion or not. The interrupted call then ends with an
        error (a ``drivers.errors.BackendError`` reads as one line to the operator) or
        with its outcome. Default: nothing (a backend whose motions cannot be stopped
        midway, as the twin's simulated strokes, which last milliseconds)."""
        return None

    # -- optional capabilities (a backend that lacks one says so) ------------------------
    def prepare(self) -> None:
        """Called by the agent right after it answered a push or a reset: get the next
        observation ready now, while the controller is busy elsewhere (the twin renders
        it; the default does nothing, and a camera must not: its frame would be old)."""
        return None

    def reseed(self, seed: int) -> None:
        """Start the host's task afresh from ``seed`` (twin: a new cell; YuMi: the goal
        stream), as a newly started agent with that seed would."""
        raise NotImplementedError(f"backend {self.kind!r} cannot be reseeded")

    def frame(self) -> npt.NDArray[np.uint8]:
        """The full camera frame as the camera gives it (BGR, HxWx3), for calibration and
        ``testbed check``; arms may be in view."""
        raise NotImplementedError(f"backend {self.kind!r} has no camera frame")

    def move_tcp(self, arm: str, xyz_mm: Sequence[float]) -> tuple[float, float, float]:
        """Calibration: bring ``arm``'s TCP to ``xyz_mm`` (the robot's world frame (wobj0),
        mm) from above;
        returns the TCP position the controller reports there."""
        raise NotImplementedError(f"backend {self.kind!r} cannot move a TCP to a point")

    def save_calibration(self, arm: str, data: Mapping[str, Any]) -> str:
        """Write ``arm``'s calibration file atomically on the host; returns its path."""
        raise NotImplementedError(f"backend {self.kind!r} has no calibration file")

    def describe(self) -> dict[str, Any]:
        """What ``testbed check`` prints of the robot's controller (a YuMi: RobotWare,
        options, serial, state, tasks, our RAPID and its zones); JSON types only, never
        a credential."""
        raise NotImplementedError(f"backend {self.kind!r} has no controller to describe")

    # -- helpers shared by the backends -------------------------------------------------
    def check_faces(self, faces: Mapping[str, Any]) -> dict[str, int]:
        """Validate a push request; ValueError names the arm and the bad face."""
        out: dict[str, int] = {}
        for arm, face in faces.items():
            if arm not in self.arm_names:
                raise ValueError(f"unknown arm {arm!r}; this host has {list(self.arm_names)}")
            if type(face) is not int and not isinstance(face, np.integer):
                raise ValueError(f"arm {arm!r}: face must be an int, got {face!r}")
            if not 0 <= int(face) < NUM_ACTIONS:
                raise ValueError(f"arm {arm!r}: face must be in 0..{NUM_ACTIONS - 1}, got {face}")
            out[arm] = int(face)
        return out

    def check_arms(self, arms: Sequence[str]) -> list[str]:
        unknown = [a for a in arms if a not in self.arm_names]
        if unknown:
            raise ValueError(f"unknown arm(s) {unknown}; this host has {list(self.arm_names)}")
        return list(dict.fromkeys(arms))

    def __enter__(self) -> HostBackend:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


IMAGE_SHAPE: Final = (IMAGE_SIZE, IMAGE_SIZE, 3)
