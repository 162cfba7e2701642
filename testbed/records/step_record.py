"""One timestep as the records keep it: typed, then written twice from the same values.

Why: a step lands in two places, a row of ``steps.jsonl`` (the trial's ground truth,
``testbed.records.steps``) and one frame per arm in the data store
(``testbed.records.store``: the images and labels the learner and ``testbed export``
read). The loop fills one ``StepRecord`` from its typed arrays; ``to_row()`` and
``to_frames()`` are the only two ways it is written, so neither store is parsed back
from the other and both always say the same thing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from testbed.core.types import Mode
from testbed.records.store import FRAME_DTYPE, FRAME_READINGS, MODES

__all__ = ["ArmStep", "StepRecord"]


@dataclass(frozen=True, slots=True)
class ArmStep:
    """What one arm did at one step: who acted, what, and what came of it."""

    robot: str
    mode: Mode
    human: int | None
    action: int | None
    success: bool
    violation: bool
    uncertainty: float | None
    """None when the arm faulted (the policy never saw it)."""
    risk: float | None
    key: tuple[float, ...]
    refused: str | None = None
    """Why the host did not push (``mode`` is then ``refused``)."""
    served: int | None = None
    """With a human on the arm: the steps that human already spent on this intervention
    (0 on its first step; ``Allocator.served``), so an intervention is the run of steps
    from a 0. None without a human."""
    first: tuple[int, float | None] | None = None
    """On the step of the intervention's first action (a teleop's first push, a reset's
    confirmation): (steps from the assignment, i.e. ``served``; the seconds the human
    reported, or None)."""
    monitor: dict[str, float] | None = None
    """The failure monitor's scores of the arm beyond ``uncertainty`` and ``risk``
    (``novelty``, ``goal_risk`` when its critic ran, ...; testbed/monitor/), so a run's
    rows alone can score every signal as a failure predictor. None when faulted."""
    waited: int | None = None
    """With no human after the allocation and waiting for one (idle after a violation,
    or queued: its key asked for a human and none was free): the steps it has waited,
    this one included (``Allocator.waited``, 1 on a wait's first step); None when not
    waiting. ``served``'s other side: a wait is the run of steps from a 1."""
    readings: dict[str, float] | None = None
    """What the robot host measured of this arm's push, by name (``push_s``: its
    duration on the host), from the ``PushResult``: the one generic path of host
    measurements, so a new one reaches the row with no edit here. None when the host
    measured nothing (the twin: its rows stay the same for one seed)."""

    def to_entry(self) -> dict[str, Any]:
        entry: dict[str, Any] = {
            "robot": self.robot,
            "mode": str(self.mode),
            "human": self.human,
            "action": self.action,
            "success": self.success,
            "violation": self.violation,
            "uncertainty": self.uncertainty,
            "risk": self.risk,
            "key": list(self.key),
        }
        if self.refused is not None:
            entry["refused"] = self.refused
        if self.served is not None:
            entry["served"] = self.served
        if self.first is not None:
            entry["first"] = {"steps": self.first[0], "s": self.first[1]}
        if self.monitor:
            entry["monitor"] = dict(self.monitor)
        if self.waited is not None:
            entry["waited"] = self.waited
        if self.readings:
            entry["readings"] = dict(self.readings)
        return entry


@dataclass(slots=True)
class StepRecord:
    """Step ``t`` of a run: every arm's ``ArmStep`` and observation, the step's events."""

    t: int
    session: int
    """0, then +1 at every resume (no critic transition crosses a session)."""
    arms: list[ArmStep]
    images: npt.NDArray[np.uint8]
    """(N, 64, 64, 3): what each arm's policy saw (zeros when not observed)."""
    observed: npt.NDArray[np.bool_]
    goals: npt.NDArray[np.float32]
    """(N, 2) canonical; NaN when not observed."""
    faults: dict[str, str] = field(default_factory=dict)
    away: list[int] = field(default_factory=list)
    """Humans not available at this step's allocation (web console); absent if none."""
    released: list[dict[str, Any]] = field(default_factory=list)
    """Interventions ended before the allocation: ``{"robot", "human", "why"}``."""
    wall_time: float = 0.0
    duration_s: float = 0.0

    def to_row(self) -> dict[str, Any]:
        """The steps.jsonl row (its schema: ``testbed.records.steps.validate_step``)."""
        row: dict[str, Any] = {"t": self.t, "robots": [a.to_entry() for a in self.arms]}
        if self.faults:
            row["faults"] = dict(self.faults)
        if self.away:  # only when someone is away: rows of runs without are as they were
            row["away"] = list(self.away)
        if self.released:
            row["released"] = list(self.released)
        # Timing rides along for the lab: it is the one part of a row that differs
        # between two runs of the same seed.
        row["wall_time"] = self.wall_time
        row["duration_s"] = self.duration_s
        return row

    def to_frames(self) -> np.ndarray:
        """The data store's frames of this step, one per arm (``FRAME_DTYPE``)."""
        n = len(self.arms)
        f = np.zeros(n, FRAME_DTYPE)
        f["t"] = self.t
        f["arm"] = np.arange(n)
        f["session"] = self.session
        f["observed"] = self.observed
        f["image"] = self.images
        f["goal"] = self.goals
        f["wall_time"] = self.wall_time
        for i, a in enumerate(self.arms):
            f["mode"][i] = MODES.index(str(a.mode))
            f["human"][i] = -1 if a.human is None else a.human
            f["action"][i] = -1 if a.action is None else a.action
            f["success"][i] = a.success
            f["violation"][i] = a.violation
            f["uncertainty"][i] = np.nan if a.uncertainty is None else a.uncertainty
            f["risk"][i] = np.nan if a.risk is None else a.risk
            for name in FRAME_READINGS:  # the host's readings that are columns too
                f[name][i] = (a.readings or {}).get(name, np.nan)
        return f

    @classmethod
    def from_row(cls, row: dict[str, Any], session: int, images: np.ndarray,
                 observed: np.ndarray, goals: np.ndarray) -> StepRecord:
        """A record from a steps.jsonl row and the step's observation (tools and tests
        that make data stores from rows)."""
        arms = [ArmStep(r["robot"], Mode(r["mode"]), r["human"], r["action"],
                        bool(r["success"]), bool(r["violation"]), r["uncertainty"],
                        r["risk"], tuple(r.get("key", ())), r.get("refused"),
                        r.get("served"), _first(r.get("first")), r.get("monitor"),
                        r.get("waited"), _readings(r.get("readings")))
                for r in row["robots"]]
        return cls(int(row["t"]), session, arms, images, observed, goals,
                   dict(row.get("faults", {})), list(row.get("away", [])),
                   list(row.get("released", [])), float(row.get("wall_time", 0.0)),
                   float(row.get("duration_s", 0.0)))


def _first(entry: dict[str, Any] | None) -> tuple[int, float | None] | None:
    """A row's ``first`` back as ``ArmStep.first``."""
    if entry is None:
        return None
    return int(entry["steps"]), None if entry.get("s") is None else float(entry["s"])


def _readings(entry: dict[str, Any] | None) -> dict[str, float] | None:
    """A row's ``readings`` back as ``ArmStep.readings`` (None when absent or empty, as
    ``to_entry`` writes nothing then)."""
    return {str(k): float(v) for k, v in entry.items()} if entry else None
