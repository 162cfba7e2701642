"""Named types for what flows between the parts of the testbed.

The fleet loop, the drivers, the learner and the console meet through these plain
dataclasses (as Stable-Baselines3's ``type_aliases``), so no part needs to import
another part's internals. Nothing heavy is imported here.

Conventions shared by every part:

* A robot is named ``"<host>/<arm>"`` (``"cell0/left"``).
* Images are ``(64, 64, 3)`` ``uint8`` RGB in the arm's *canonical* frame: right-arm
  crops are mirrored left-right into it, so one policy serves both arms.
* Canonical coordinates are image units in ``[0, 1]^2``: ``(0, 0)`` is the top-left
  corner of the arm's 64x64 crop, ``x`` grows right, ``y`` grows down.
* Action ``k`` in ``Discrete(4)`` pushes the cube face whose push moves the cube
  (about) along ``FACE_DIRECTIONS[k]`` in the canonical frame: 0 up, 1 left, 2 down,
  3 right. (Object-centric: the pusher comes in along the face's real normal, which is
  the cube's yaw away from that direction.)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum, IntEnum
from typing import Final

import numpy as np
import numpy.typing as npt

ImageArray = npt.NDArray[np.uint8]
"""(64, 64, 3) uint8 RGB, or a batch (N, 64, 64, 3)."""

IMAGE_SIZE: Final = 64
NUM_ACTIONS: Final = 4
FACE_DIRECTIONS: Final[tuple[tuple[float, float], ...]] = (
    (0.0, -1.0),  # 0: up
    (-1.0, 0.0),  # 1: left
    (0.0, 1.0),  # 2: down
    (1.0, 0.0),  # 3: right
)
SUCCESS_RADIUS: Final = 6.0 / 64.0
MIN_GOAL_DISTANCE: Final = 12.0 / 64.0
MAX_PUSHES_PER_GOAL: Final = 50


class _Named(str, Enum):
    """A str enum that prints and formats as its value, as ``enum.StrEnum`` (Python
    3.11) does: ``core`` runs on a robot host's Python too, 3.10 included."""

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, format_spec: str) -> str:
        return format(str(self.value), format_spec)


class Mode(_Named):
    """What a robot did in a timestep (the ``mode`` field of steps.jsonl)."""

    AUTONOMOUS = "autonomous"
    TELEOP = "teleop"
    RESET = "reset"
    IDLE = "idle"
    FAULT = "fault"
    REFUSED = "refused"
    """The host could not push (e.g. the cube not found): neither autonomous nor human."""


class InterventionKind(_Named):
    TELEOP = "teleop"
    RESET = "reset"


DEFAULT_PRE_STEPS: Final = 3
"""k, the pre-intervention window in steps (``learning.pre_intervention_steps``; here so
that learning's config and the records' rules share it): docs/notes/learning.md, "Frame
classes", says how it was chosen from twin runs."""


class FrameClass(IntEnum):
    """Who produced a frame's action, as learning by class reads it (issue 30; the rules:
    ``testbed/records/frame_classes.py``). Codes are stored in exports: append only."""

    DEMO = 0
    """An offline demonstration (theta_0's data; never among a run's frames)."""
    ROBOT = 1
    """The policy pushed (mode autonomous)."""
    TELEOP = 2
    """A human pushed (mode teleop, with an action)."""
    RESET = 3
    """A human's hard reset (mode reset): the recovery."""
    PRE_INTERVENTION = 4
    """A robot push among the arm's last k steps before a human took it, same episode."""
    NONE = 5
    """Nobody acted: idle, fault, refused, or a teleop step the human let pass."""


class EpisodeOutcome(IntEnum):
    """How the arm's episode that holds a frame ended. Codes are stored: append only."""

    OPEN = 0
    """Not ended in the records: the run stopped, or a resume cut it (a new goal)."""
    SUCCESS = 1
    VIOLATION = 2
    GOAL_CHANGE = 3
    """A new goal without a success (the twin's timeout after MAX_PUSHES_PER_GOAL)."""
    UNKNOWN = 4
    """A fault hid the end: the goal changed across frames that were not observed."""


@dataclass(frozen=True, slots=True)
class ArmObservation:
    """One arm's view at the start of a timestep, as its host reported it."""

    robot: str
    image: ImageArray
    violating: bool
    """The cube is outside the workspace and the arm waits for a hard reset."""
    goal: tuple[float, float]
    """Goal centre in canonical coordinates."""
    expert_action: int | None = None
    """Ground-truth best push; only a twin host knows it (the scripted human uses it)."""


@dataclass(frozen=True, slots=True)
class PushResult:
    """Outcome of one arm's push (or of its waiting) in a timestep."""

    robot: str
    action: int | None
    success: bool
    violation: bool
    """True on the step whose push took the cube out (an event, once per violation)."""
    refused: str | None = None
    """Why the host did not push this arm (None: it pushed, or it was not asked to)."""
    readings: tuple[tuple[str, float], ...] = ()
    """What the robot host measured of this push, ``(name, value)`` sorted by name
    (``("push_s", 1.8)``: the push's duration on the host): the backend's
    ``ArmOutcome.readings``, carried to the arm's row (``"readings"``) unchanged. Pairs,
    not a dict, so the result stays immutable and hashable; ``dict(result.readings)``
    reads it. Empty when the host measured nothing (the twin) or did not push."""


@dataclass(frozen=True, slots=True)
class Fault:
    """An arm whose host could not serve it this step; the trial goes on without it."""

    robot: str
    reason: str
    traceback: str = ""


@dataclass(frozen=True, slots=True)
class HumanRequest:
    """What the fleet loop asks one human to do for one arm this timestep."""

    robot: str
    human: int
    kind: InterventionKind
    observation: ArmObservation
    served: int
    """Timesteps this human has already spent on this intervention (0 on the first)."""
    min_steps: int
    """t_T for teleop, t_R for a hard reset."""
    key: tuple[float, ...] = ()
    reason: dict[str, float] = field(default_factory=dict)
    """Why the arm was chosen: the priority's named signals (c, u, r, ...)."""


@dataclass(frozen=True, slots=True)
class HumanResponse:
    """A human's answer: a push for teleop, or whether a hard reset is complete."""

    robot: str
    action: int | None = None
    reset_done: bool = False
    waited_s: float | None = None
    """Seconds from when this human was first shown this intervention to this answer,
    on the answer that carries the intervention's first action (its first push, or a
    reset's confirmation); None on every other answer, or from a human that does not
    measure it. The loop records it with the steps it took (the step row's ``first``):
    the per-human table's "time to first action"."""


@dataclass(slots=True)
class RobotStatus:
    """What the overview shows of one robot: its latest image and mode."""

    robot: str
    mode: Mode
    image: ImageArray | None
    human: int | None = None
    waited: int | None = None
    """Steps this robot has waited for a human, this one included (its row's
    ``"waited"``); None when it is not waiting. Both consoles show it."""


@dataclass(frozen=True, slots=True)
class HumanEstimate:
    """What the run's own records say of one human so far (``testbed.fleet.operators``):
    posterior means, each shrunk towards the fleet's pooled figure, so a human with no
    data reads as the fleet's average. Shown live in the consoles' overview and read by
    the matched allocation (``algorithm.operators = "matched"``)."""

    human: int
    """The human's index (the rows' ``human``; the config's ``humans.people`` order)."""
    skill: float
    """Successes per teleop push."""
    violations: float
    """Violations per teleop push (the cube taken out of the workspace)."""
    reset_steps: float
    """Steps a hard reset takes, from its assignment to its confirmation."""
    latency_steps: float
    """Steps from a teleop's assignment to its first push (0: at once)."""
    pushes: int
    """Teleop pushes seen (the evidence behind ``skill`` and ``violations``)."""
    resets: int = 0
    """Confirmed hard resets seen (the evidence behind ``reset_steps``)."""


@dataclass(slots=True)
class FleetStatus:
    """The live counters of a trial (the progress bar and the console overview)."""

    t: int
    steps: int
    successes: int = 0
    hard_resets: int = 0
    idle_time: int = 0
    human_actions: int = 0
    rohe: float = 0.0
    robots: list[RobotStatus] = field(default_factory=list)
    paused: bool = False
    operators: list[HumanEstimate] = field(default_factory=list)
    """Per human, by index: the estimates so far (empty before the first step)."""
    away: list[int] = field(default_factory=list)
    """The humans away this step (their consoles closed: the row's ``"away"``)."""
    last_fault: tuple[int, str, str] | None = None
    """The newest fault so far: (step, robot, reason), an arm's host faulted at the
    observation or at the push (the latter also in the row's ``"faults"``)."""

    def health(self, names: Sequence[str] = ()) -> str:
        """A run's health at a glance (issue 44), for the progress line and the web
        overview: the arms faulted now, the arms waiting for a person (the longest
        wait), the humans away, the newest fault; empty when all is well."""
        parts = []
        faulted = [r.robot for r in self.robots if r.mode is Mode.FAULT]
        if faulted:
            parts.append(f"faulted {len(faulted)} ({', '.join(faulted)})")
        waits = [r.waited for r in self.robots if r.waited is not None]
        if waits:
            parts.append(f"waiting {len(waits)} (longest {max(waits)} steps)")
        if self.away:
            who = [names[h] if h < len(names) and names[h] else f"human {h}"
                   for h in self.away]
            parts.append(f"away: {', '.join(who)}")
        if self.last_fault is not None:
            t, robot, why = self.last_fault
            short = why if len(why) <= 90 else why[:87] + "..."
            parts.append(f"last fault at step {t}, {robot}: {short}")
        return "; ".join(parts)
