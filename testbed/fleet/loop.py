"""The fleet loop: one Fleet-DAgger timestep after another
(docs/ARCHITECTURE.md, "The timestep").

::

    observe (all hosts at once) --> signals (act) --> keys (priority) --> Allocator
        --> humans.act --> execute (all hosts at once) --> log (fsync)
           \\__ training step runs here, in a thread, from observe to log __/

The training step of timestep t starts as soon as its data is in (right after the
observation, which completes the last step's transitions) and runs while the learner
acts, the humans answer and the arms push; it is joined before the step is logged.
``act`` reads a copy of the networks brought up to date just before the training step
starts (``Learner.acting_copy()``), so the policy used at t is always the one after
exactly t training steps, whatever the timing: a twin trial with scripted humans is
reproducible, overlap included, and its records are those of the serial order (act,
then train). At N = 100 arms the policy's forward pass is a large part of a step;
overlapping it with training makes the step cost the training step, not the sum
(docs/notes/fleet.md). The loop owns no hardware and no GUI: it talks to a
``HostFleet``-like object, a ``Humans`` and a ``Learner`` only through their small APIs.

Humans who come and go (the web console, ``testbed.core.humans.Presence``): right before
each allocation the loop asks ``presence_of(humans)``. Humans in ``gone`` (away past
the console's grace period) lose the arm they are on (``Allocator.release_human``),
and the row says so (``"released": [{"robot", "human", "why": "away"}]``); every
human not available is handed to the allocator as such, which gives them no new
intervention, and the row lists them (``"away": [human, ...]``). Both keys appear only
when non-empty, so humans without ``presence()`` (scripted, the OpenCV console) write
the rows they always wrote. How long the fleet waits on an away human's answer is the
console's business (its timeout inside ``act``), not the loop's.

Over 450 lines, on purpose: one timestep (observe, act, allocate, ask, execute, record),
read top to bottom; the allocation's state is in ``allocator.py``, the records' in
``testbed/records/``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from testbed.core.hosts import LoopHosts
from testbed.core.humans import Humans, presence_of
from testbed.core.interrupts import critical
from testbed.core.types import (
    IMAGE_SIZE,
    ArmObservation,
    Fault,
    FleetStatus,
    HumanRequest,
    HumanResponse,
    InterventionKind,
    Mode,
    PushResult,
    RobotStatus,
)
from testbed.fleet.algorithms import Algorithm
from testbed.fleet.allocator import Allocator
from testbed.fleet.interventions import FirstActions
from testbed.fleet.operators import OperatorModel
from testbed.fleet.priorities import LEARNED_SIGNALS, PrioritySignals
from testbed.records import store as rundata
from testbed.records.step_record import ArmStep, StepRecord
from testbed.records.steps import RunWriter
from testbed.records.store import RunDataWriter


class LearnerLike(Protocol):
    def act(self, images: np.ndarray) -> Any: ...

    def add_human(self, images: np.ndarray, actions: np.ndarray,
                  labellers: np.ndarray | None = None) -> None: ...

    def add_transitions(
        self,
        images: np.ndarray,
        actions: np.ndarray,
        next_images: np.ndarray,
        violation: np.ndarray,
        success: np.ndarray,
    ) -> None: ...

    def train_step(self) -> dict[str, float]: ...


class ActorLike(Protocol):
    """What ``Learner.acting_copy()`` returns (``testbed.learning.actor.Actor``)."""

    def sync(self) -> None: ...

    def act(self, images: np.ndarray) -> Any: ...


@dataclass
class _Decided:
    out: Any
    keys: np.ndarray
    faulted: np.ndarray
    pushes: dict[str, int]
    resets: list[str]
    modes: dict[str, Mode]
    humans_of: dict[str, int | None]
    away: list[int] = field(default_factory=list)
    """Humans not available at this step's allocation (sorted)."""
    released: list[dict[str, Any]] = field(default_factory=list)
    """Interventions ended before the allocation: ``{"robot", "human", "why"}``."""
    held: dict[str, str] = field(default_factory=dict)
    """Pushes not sent because a human is resetting an arm of the same cell: robot ->
    why (recorded as ``refused``, with the face the policy or the human chose)."""
    held_faces: dict[str, int] = field(default_factory=dict)
    served: dict[str, int] = field(default_factory=dict)
    """Robot -> steps its human has already spent on the intervention (0: the first)."""
    first: dict[str, float | None] = field(default_factory=dict)
    """Robots whose human acted for the first time in the intervention this step ->
    the seconds the human reported (``HumanResponse.waited_s``)."""
    waited: dict[str, int] = field(default_factory=dict)
    """Robots waiting for a human after this step's allocation -> the steps they have
    waited, this one included (``Allocator.waited``; the row's ``"waited"``)."""


@dataclass
class _Observed:
    observations: Mapping[str, ArmObservation | Fault]
    images: np.ndarray
    violating: np.ndarray
    observed: np.ndarray
    goals: np.ndarray


@dataclass
class StepOutcome:
    """Everything one timestep produced, for the caller's progress display."""

    t: int
    row: dict[str, Any]
    status: FleetStatus
    train_info: dict[str, float] = field(default_factory=dict)


class FleetLoop:
    """Runs timesteps of one trial; the caller owns setup, records' folder and teardown."""

    def __init__(
        self,
        *,
        hosts: LoopHosts,
        humans: Humans,
        learner: LearnerLike,
        algorithm: Algorithm,
        writer: RunWriter,
        steps: int,
        num_humans: int,
        t_T: int,
        t_R: int,
        after_step: Callable[[int], None] | None = None,
        overlap_act: bool = True,
        data: RunDataWriter | None = None,
        session: int = 0,
        cells: Mapping[str, str] | None = None,
    ) -> None:
        self.hosts = hosts
        self.cells = dict(cells or {})
        """Robot -> the cell it shares with other robots (a YuMi's two arms over one
        table); robots not in it share nothing. See :meth:`_hold_cells`."""
        self.humans = humans
        self.learner = learner
        self.algorithm = algorithm
        self.allocator: Allocator = algorithm.allocator
        self.writer = writer
        self.steps = steps
        self.num_humans = num_humans
        self.t_T = t_T
        self.t_R = t_R
        self.robots = list(hosts.robot_names)
        self.data = data
        self.session = session
        self._last: np.ndarray | None = None  # the last step's frames (its pushes)
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="train")
        self._after_step = after_step
        # Act on the learner's acting copy (beside the training step when the algorithm
        # learns, synced before it; made now, from the weights the trial starts with, for
        # one that does not; compiled when learning.compile_act). A learner without one
        # (a test's fake) acts itself, before the training step starts: the serial order.
        make_actor = getattr(learner, "acting_copy", None)
        self._actor: ActorLike | None = (
            make_actor() if overlap_act and callable(make_actor) else None)
        self.status = FleetStatus(t=0, steps=steps)
        self._first_actions = FirstActions()
        self.operators = OperatorModel(num_humans, t_T, t_R)
        """What the rows say of each human (``status.operators``; the matched gains)."""
        self._feed = rundata.label_feed(learner, len(self.robots))
        """The robot's own pushes, to a learner that learns from them, as episodes end."""
        self._monitored = ("novelty", "ood",
                           *(("goal_risk",) if "goal" in algorithm.spec.critics else ()))
        """What each arm's row keeps under ``monitor`` beyond uncertainty and risk, for
        scoring failure prediction from the rows: novelty, ood when the learner gives it,
        goal risk when its critic runs (the trial sets the critics from the same spec)."""

    # ---- counters -------------------------------------------------------------------
    def restore_counters(self, rows: Sequence[Mapping[str, Any]]) -> None:
        """Rebuild the live counters (the humans' estimates too) from the records of a
        resumed trial."""
        for row in rows:
            self._count(row)
        self._first_actions.restore(rows)

    def _count(self, row: Mapping[str, Any]) -> None:
        s = self.status
        for r in row["robots"]:
            s.successes += bool(r["success"])
            s.hard_resets += bool(r["violation"])
            s.idle_time += r["mode"] in (Mode.IDLE, Mode.RESET)
            s.human_actions += r["mode"] in (Mode.TELEOP, Mode.RESET)
        n = max(len(self.robots), 1)
        s.rohe = (self.num_humans / n) * s.successes / (1 + s.human_actions)
        self.operators.observe(row)
        s.operators = self.operators.estimates()

    def restore_feed(self, steps: Iterable[np.ndarray]) -> None:
        """A resumed trial: the episodes still open after the steps already run (the
        data store's frames of them, in order), so the robot pushes that end later reach
        the learner as they would have in an unbroken run (the replay gave it the rest)."""
        if self._feed is not None and self.algorithm.learns:
            self._feed.catch_up(steps)

    # ---- one timestep ---------------------------------------------------------------
    def _decide(self, t: int, observations: Mapping[str, ArmObservation | Fault],
                violating: np.ndarray, out: Any) -> _Decided:
        """Keys, allocation, the humans' answers: what every arm does at step t."""
        faulted = np.array([not isinstance(observations.get(r), ArmObservation)
                            for r in self.robots])
        available, away, released = self._presence(t)
        signals = PrioritySignals(  # every learned signal, by its name in PolicyOutput
            t=t,
            violating=violating & ~faulted,
            faulted=faulted,
            available=available,
            features=getattr(out, "features", None),
            waited=self.allocator.waited,  # so far: up to the last step's allocation
            **{name: None if getattr(out, name, None) is None
               else np.asarray(getattr(out, name), dtype=float)
               for name in sorted(LEARNED_SIGNALS)},
        )
        gains = (self.operators.gains(signals.violating) if self.algorithm.matched
                 else None)  # "blind": Algorithm 1, whatever the rows say
        assignment = self.algorithm.step(signals, gains)
        keys = np.asarray(self.algorithm.last_keys, dtype=float)
        requests = self._requests(observations, assignment, faulted, keys, out)
        responses = self.humans.act(requests, t) if requests else {}
        d = _Decided(out, keys, faulted, {}, [], {}, {}, away, released)
        d.waited = {r: int(w) for r, w in zip(self.robots, self.allocator.waited, strict=True)
                    if w > 0}
        self._assign_modes(d, assignment, violating, responses)
        self._hold_cells(d)
        return d

    def _hold_cells(self, d: _Decided) -> None:
        """The policy for a hard reset while a sibling arm would push: a person's hands
        are in a shared cell (a YuMi's table) from the step a reset of one of its arms
        is assigned until the step it is confirmed, so no other arm of that cell moves in
        those steps. Their pushes are held: not sent, recorded as ``refused`` ("held: ...")
        with the face chosen, and the arm is free again the step after the reset ends.
        Robots of separate cells (the twin's) are never held."""
        resetting = {self.cells[r]: r for r in self.robots
                     if d.modes[r] is Mode.RESET and r in self.cells}
        for r in list(d.pushes):
            cell = self.cells.get(r)
            if cell in resetting and resetting[cell] != r:
                d.held[r] = (f"held: a person is resetting {resetting[cell]} in the same "
                             f"cell ({cell})")
                d.held_faces[r] = d.pushes.pop(r)

    def _requests(self, observations: Mapping[str, ArmObservation | Fault],
                  assignment: np.ndarray, faulted: np.ndarray, keys: np.ndarray,
                  out: Any) -> list[HumanRequest]:
        """One request per arm the allocator gave a human (faulted arms aside)."""
        kinds, served = self.allocator.kinds, self.allocator.served
        requests: list[HumanRequest] = []
        for i, r in enumerate(self.robots):
            h = int(assignment[i])
            if h < 0 or faulted[i]:
                continue
            kind = kinds[i]
            assert kind is not None
            requests.append(
                HumanRequest(
                    robot=r,
                    human=h,
                    kind=kind,
                    observation=observations[r],  # type: ignore[arg-type]
                    served=int(served[i]),
                    min_steps=self.t_T if kind is InterventionKind.TELEOP else self.t_R,
                    key=tuple(float(k) for k in keys[i]),
                    reason=self.algorithm.reason(i) | self.algorithm.row_fields(i)
                    | {"uncertainty": float(out.uncertainty[i]), "risk": float(out.risk[i])},
                )
            )
        return requests

    def _assign_modes(self, d: _Decided, assignment: np.ndarray, violating: np.ndarray,
                      responses: Mapping[str, HumanResponse]) -> None:
        """Each arm's mode, human and push (or reset) from the allocation and answers."""
        kinds, served = self.allocator.kinds, self.allocator.served
        for i, r in enumerate(self.robots):
            h = int(assignment[i])
            d.humans_of[r] = h if h >= 0 else None
            answer = responses.get(r)
            acted = False
            if d.faulted[i]:
                d.modes[r] = Mode.FAULT
            elif h >= 0 and kinds[i] is InterventionKind.RESET:
                d.modes[r] = Mode.RESET
                if answer is not None and answer.reset_done:
                    d.resets.append(r)
                    acted = True
            elif violating[i]:
                d.modes[r] = Mode.IDLE
            elif h >= 0:
                d.modes[r] = Mode.TELEOP
                if answer is not None and answer.action is not None:
                    d.pushes[r] = int(answer.action)  # else the human let the step pass
                    acted = True
            else:
                d.modes[r] = Mode.AUTONOMOUS
                d.pushes[r] = int(d.out.actions[i])
            if h >= 0 and not d.faulted[i]:
                d.served[r] = int(served[i])
                if self._first_actions.first(r, d.served[r], acted):
                    d.first[r] = None if answer is None else answer.waited_s

    def _presence(self, t: int) -> tuple[np.ndarray | None, list[int], list[dict[str, Any]]]:
        """Who may be assigned at this step: (available mask or None, away, released).

        Humans without ``presence()`` give ``(None, [], [])``: the allocation and the row
        of a run without away humans. A human in ``gone`` is away whatever ``available``
        says, and the arm it is on is freed now, before the allocation, so a present
        human may take that arm at this very step.
        """
        p = presence_of(self.humans, t)
        if p is None:
            return None, [], []
        given = np.asarray(p.available)
        if given.dtype != np.bool_ or given.shape != (self.num_humans,):
            raise ValueError(f"humans.presence().available must be bool with shape "
                             f"({self.num_humans},), got {given.dtype} {given.shape}")
        available = given.copy()
        released: list[dict[str, Any]] = []
        for h in sorted(p.gone):
            if not 0 <= h < self.num_humans:
                raise ValueError(f"humans.presence().gone has human {h}, not in "
                                 f"[0, {self.num_humans})")
            available[h] = False
            arm = self.allocator.release_human(h)
            if arm is not None:
                released.append({"robot": self.robots[arm], "human": int(h), "why": "away"})
        away = [int(h) for h in np.flatnonzero(~available)]
        return available, away, released

    def _observe(self) -> _Observed:
        """Every arm's observation, as the arrays the learner and the records take."""
        observations = self.hosts.observe()
        n = len(self.robots)
        seen = _Observed(observations, np.zeros((n, IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8),
                         np.zeros(n, dtype=bool), np.zeros(n, dtype=bool),
                         np.full((n, 2), np.nan, dtype=np.float32))
        for i, r in enumerate(self.robots):
            o = observations.get(r)
            if isinstance(o, ArmObservation):
                seen.images[i] = o.image
                seen.violating[i] = o.violating
                seen.observed[i] = True
                seen.goals[i] = o.goal
        return seen

    def step(self, t: int) -> StepOutcome:
        started = time.monotonic()
        seen = self._observe()
        if self.algorithm.learns and self._last is not None:  # training step t's last data
            rundata.add_transitions(self.learner, self._last, seen.observed, seen.images)
        training: Future[dict[str, float]] | None = None
        if self._actor is not None and self.algorithm.learns:
            self._actor.sync()  # train beside act: act reads the up-to-date copy
            training = self._executor.submit(self.learner.train_step)
        try:
            out = (self._actor or self.learner).act(seen.images)
            if training is None and self.algorithm.learns:  # serial: after act
                training = self._executor.submit(self.learner.train_step)
            d = self._decide(t, seen.observations, seen.violating, out)
            results = self.hosts.execute(d.pushes, d.resets)
        except BaseException:
            if training is not None:
                training.result()
            raise
        train_info = training.result() if training is not None else {}
        record = self._record(t, d, results, seen)
        record.wall_time = time.time()
        record.duration_s = time.monotonic() - started
        row, frames = record.to_row(), record.to_frames()
        with critical():  # the data first: a step in steps.jsonl always has its frames
            if self.data is not None:
                self.data.append(frames)
            self.writer.write_step(row)
        self._count(row)
        self._last = frames
        self.algorithm.observe(frames)  # the monitor's alarm learns from the step's ends
        if self.algorithm.learns:
            rundata.add_labels(self.learner, frames)
            if self._feed is not None:
                self._feed.step(self.learner, frames)  # type: ignore[arg-type]
        self.status.t = t + 1
        self.status.away = [int(h) for h in row.get("away", ())]
        faults = {r: o.reason for r, o in seen.observations.items() if isinstance(o, Fault)}
        faults.update(row.get("faults") or {})  # a host's fault at the push
        for robot, why in sorted(faults.items())[:1]:  # the newest, for the displays
            self.status.last_fault = (t, robot, str(why))
        self.status.robots = [
            RobotStatus(r, a.mode, seen.images[i] if not d.faulted[i] else None,
                        d.humans_of[r], a.waited)
            for i, (r, a) in enumerate(zip(self.robots, record.arms, strict=True))
        ]
        if self._after_step is not None:  # checkpoint first: a stop in show keeps step t
            self._after_step(t)
        self.humans.show(t, self.status)
        return StepOutcome(t, row, self.status, train_info)

    def _record(self, t: int, d: _Decided, results: Mapping[str, PushResult | Fault],
                seen: _Observed) -> StepRecord:
        """The step as the records keep it. The mode each arm's row records: a host's
        fault wins, then a push it refused, then what was decided."""
        uncertainty, risk = np.asarray(d.out.uncertainty), np.asarray(d.out.risk)
        monitored = {name: np.asarray(getattr(d.out, name)) for name in self._monitored
                     if getattr(d.out, name, None) is not None}
        arms = []
        for i, r in enumerate(self.robots):
            res = results.get(r)
            mode = d.modes[r]
            refused = None
            if isinstance(res, Fault):
                mode = Mode.FAULT
            elif r in d.held:
                mode, refused = Mode.REFUSED, d.held[r]
            elif r in d.pushes and isinstance(res, PushResult) and res.refused is not None:
                mode, refused = Mode.REFUSED, str(res.refused)
            ok = isinstance(res, PushResult)
            faulted = mode is Mode.FAULT
            arms.append(ArmStep(
                robot=r, mode=mode, human=d.humans_of[r],
                action=d.pushes.get(r, d.held_faces.get(r)) if not faulted else None,
                success=bool(ok and res.success),  # type: ignore[union-attr]
                violation=bool(ok and res.violation),  # type: ignore[union-attr]
                uncertainty=None if faulted else float(uncertainty[i]),
                risk=None if faulted else float(risk[i]),
                key=tuple(float(k) for k in d.keys[i]),
                refused=refused,
                served=d.served.get(r),
                first=((d.served[r], d.first[r]) if r in d.first else None),
                waited=d.waited.get(r),
                readings=(dict(res.readings) or None) if isinstance(res, PushResult) else None,
                monitor=None if faulted else ({k: float(v[i]) for k, v in monitored.items()}
                                              | self.algorithm.row_fields(i)),
            ))
        faults = {r: res.reason for r, res in results.items() if isinstance(res, Fault)}
        return StepRecord(t, self.session, arms, seen.images, seen.observed, seen.goals,
                          faults, d.away, d.released)

    def close(self) -> None:
        self._executor.shutdown(wait=True)
