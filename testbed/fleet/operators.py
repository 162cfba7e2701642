"""What the run's own records say of each human, and what each is expected to add.

Why: Algorithm 1 treats its people as interchangeable (the free humans take the chosen
arms in index order), though a lab's operators are not: one pushes the right face more
often, one takes a step to start, one is slow to put a cube back. ``OperatorModel``
learns that online from the very rows the fleet writes to ``steps.jsonl`` (one call of
:meth:`OperatorModel.observe` per row), and says, per human and arm, the expected gain of
giving that arm to that human (:meth:`OperatorModel.gains`): what the matched
allocation (``algorithm.operators = "matched"``, ``testbed.fleet.allocator``) ranks the
free humans by. It holds integer counts only, so feeding the same rows again (a resumed
trial: ``FleetLoop.restore_counters``) rebuilds it exactly, bit for bit, and its
estimates are pure functions of those counts.

What is counted, from each row's arms (as ``testbed.results.report_humans`` counts
the per-human table):

* a **teleop push**: mode ``teleop`` with an action, of the arm's ``human``; its
  ``success`` and ``violation`` are that step's;
* a **policy push**: mode ``autonomous`` with an action (pooled over every arm);
* a **first push** (latency): a row with ``first`` whose mode is not ``reset``:
  ``first.steps`` is the steps from the assignment to the push;
* a **reset**: a ``reset`` row with ``first`` (its confirmation): it took
  ``first.steps + 1`` steps.

The estimates are posterior means with pseudo-counts, in two levels (so a newcomer
starts at the fleet's pooled average, and the pooled average itself starts somewhere):

=================  ====================================  ================================
estimate           a human's own, shrunk towards          the humans' pool, shrunk towards
=================  ====================================  ================================
skill              the pool, weight ``PRIOR_PUSHES``      the policy's success per push,
                                                          weight ``POOL_PUSHES``
violations         the pool, weight ``PRIOR_PUSHES``      the policy's violations per
                                                          push, weight ``POOL_PUSHES``
latency (steps)    the pool, weight ``PRIOR_TIMES``       0 (Algorithm 1's assumption: a
                                                          person acts when assigned),
                                                          weight ``PRIOR_TIMES``
reset (steps)      the pool, weight ``PRIOR_TIMES``       t_R (the rules' minimum),
                                                          weight ``PRIOR_TIMES``
=================  ====================================  ================================

The policy's own rates are Beta(1, 1) posterior means (Laplace's rule): it pushes on
nearly every arm at every step, so its prior is gone after a step or two.

Why the humans' pool starts at the policy: before any person has pushed, nothing says a
person does better or worse than the policy, and a gain of exactly 0 (below) is what
Algorithm 1 acts on: the humans are assigned, in index order, as blind does. Evidence
then moves the pool quickly (``POOL_PUSHES`` human pushes weigh as much as the anchor).

Why ``PRIOR_PUSHES = 10``: on the twin a push succeeds about 0.3 of the time, so a rate
from n pushes has a standard error of about sqrt(0.21 / n): 0.14 at n = 10, the size of
the differences worth acting on (an expert's 0.35 against a careless person's 0.1);
with fewer, one lucky teleop (1 success in t_T = 3 pushes) would swing the ranking. At
10 pushes (three or four teleops) a person's own record weighs as much as the fleet's.

Why ``PRIOR_TIMES = 2``: a time in steps varies little between one intervention and
the next of the same person (a scripted profile's not at all), so two of their own
observations already say more than the fleet's average.

The expected gain of human h on an arm, for the intervention the arm would get:

* **teleop** (the arm is not violating): what h is expected to add over the policy on
  that arm during the t_T steps the teleop is held. h pushes on ``max(t_T - L_h, 0)``
  of them (``L_h``: latency; the steps before the first push pass without one), the
  policy would have pushed on all t_T; a push is worth its success minus its violation
  (a violation ends the episode and costs a hard reset)::

      gain = max(t_T - L_h, 0) * (s_h - v_h) - t_T * (s_policy - v_policy)

  Negative: the policy alone is expected to do better; the matched allocation then
  leaves the arm autonomous when no free human is expected to do better.
* **hard reset** (the arm is violating): faster is better, and always positive (a
  violating arm needs a person, whoever): ``gain = t_R / R_h`` (``R_h``: h's reset
  steps; 1 for a person who takes t_R, the rules' minimum).

Gains depend on a human's counts only, never on their index, so humans with the same
records get exactly the same gains (and the matched allocation is then exactly blind's).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from testbed.core.types import HumanEstimate, Mode

__all__ = [
    "POOL_PUSHES",
    "PRIOR_PUSHES",
    "PRIOR_TIMES",
    "OperatorModel",
]

PRIOR_PUSHES: Final = 10.0
"""Pseudo-pushes behind a human's skill and violation rate: the pool's (module doc)."""
POOL_PUSHES: Final = 10.0
"""Pseudo-pushes behind the humans' pooled rates: the policy's (module doc)."""
PRIOR_TIMES: Final = 2.0
"""Pseudo-observations behind a human's latency and reset time, and the pool's."""
POLICY_PRIOR: Final = (1.0, 1.0)
"""Beta(successes, failures) pseudo-counts of the policy's rates: Laplace's rule."""

_TELEOP: Final = str(Mode.TELEOP)
_RESET: Final = str(Mode.RESET)
_AUTONOMOUS: Final = str(Mode.AUTONOMOUS)


def _mean(total: float, n: float, prior_mean: float, weight: float) -> float:
    """The posterior mean of ``n`` observations summing to ``total`` with ``weight``
    pseudo-observations at ``prior_mean``; exactly ``prior_mean`` without data (no
    rounding of ``weight * m / weight``: a newcomer's estimate IS the pool's)."""
    if n == 0:
        return prior_mean
    return (total + weight * prior_mean) / (n + weight)


@dataclass(slots=True)
class _Counts:
    """One human's (or the policy's) integer counts: what the rows showed."""

    pushes: int = 0
    successes: int = 0
    violations: int = 0
    teleops: int = 0
    """First pushes seen (teleop interventions with a push)."""
    latency_sum: int = 0
    resets: int = 0
    """Confirmed resets seen."""
    reset_sum: int = 0


class OperatorModel:
    """Per-human estimates and expected gains, learned online from step rows.

    ``observe(row)`` once per row, in order (live: after the row is written; resumed:
    the rows already written, again). ``estimates()`` for the consoles and the report,
    ``gains(violating)`` for the matched allocation.
    """

    def __init__(self, num_humans: int, t_T: int, t_R: int) -> None:
        if num_humans < 0 or t_T < 1 or t_R < 1:
            raise ValueError(f"OperatorModel needs num_humans >= 0, t_T >= 1, t_R >= 1; "
                             f"got {num_humans}, {t_T}, {t_R}")
        self.num_humans: Final[int] = int(num_humans)
        self.t_T: Final[int] = int(t_T)
        self.t_R: Final[int] = int(t_R)
        self._humans = [_Counts() for _ in range(self.num_humans)]
        self._policy = _Counts()
        self.rows = 0
        """How many rows it has seen."""

    # ---- learning from rows ---------------------------------------------------------
    def observe(self, row: Mapping[str, Any]) -> None:
        """Count one step row (a ``steps.jsonl`` row, or ``StepRecord.to_row()``)."""
        self.rows += 1
        for r in row["robots"]:
            mode = str(r["mode"])
            pushed = r.get("action") is not None
            if mode == _AUTONOMOUS:
                if pushed:
                    _push(self._policy, r)
                continue
            h = r.get("human")
            if h is None or not 0 <= int(h) < self.num_humans:
                continue
            c = self._humans[int(h)]
            if mode == _TELEOP and pushed:
                _push(c, r)
            first = r.get("first")
            if first is None:
                continue
            steps = int(first["steps"])
            if mode == _RESET:
                c.resets += 1
                c.reset_sum += steps + 1
            else:  # a teleop's first push (a push the host refused or a cell held too)
                c.teleops += 1
                c.latency_sum += steps

    def observe_all(self, rows: Iterable[Mapping[str, Any]]) -> None:
        """``observe`` each row, in order (a resumed trial's rows, a finished run's)."""
        for row in rows:
            self.observe(row)

    # ---- what the counts say --------------------------------------------------------
    def policy_success(self) -> float:
        """The policy's successes per autonomous push, pooled over arms."""
        p = self._policy
        a, b = POLICY_PRIOR
        return (p.successes + a) / (p.pushes + a + b)

    def policy_violations(self) -> float:
        """The policy's violations per autonomous push, pooled over arms."""
        p = self._policy
        a, b = POLICY_PRIOR
        return (p.violations + a) / (p.pushes + a + b)

    def pooled(self) -> HumanEstimate:
        """The humans' pool (every human's records together): a newcomer's estimates.
        ``human`` is -1: it is nobody's."""
        tot = _Counts()
        for c in self._humans:
            for f in fields(_Counts):
                setattr(tot, f.name, getattr(tot, f.name) + getattr(c, f.name))
        return HumanEstimate(
            human=-1,
            skill=_mean(tot.successes, tot.pushes, self.policy_success(), POOL_PUSHES),
            violations=_mean(tot.violations, tot.pushes, self.policy_violations(),
                             POOL_PUSHES),
            reset_steps=_mean(tot.reset_sum, tot.resets, float(self.t_R), PRIOR_TIMES),
            latency_steps=_mean(tot.latency_sum, tot.teleops, 0.0, PRIOR_TIMES),
            pushes=tot.pushes, resets=tot.resets)

    def estimates(self) -> list[HumanEstimate]:
        """Per human, by index: the posterior means, each shrunk towards the pool."""
        pool = self.pooled()
        return [HumanEstimate(
            human=h,
            skill=_mean(c.successes, c.pushes, pool.skill, PRIOR_PUSHES),
            violations=_mean(c.violations, c.pushes, pool.violations, PRIOR_PUSHES),
            reset_steps=_mean(c.reset_sum, c.resets, pool.reset_steps, PRIOR_TIMES),
            latency_steps=_mean(c.latency_sum, c.teleops, pool.latency_steps, PRIOR_TIMES),
            pushes=c.pushes, resets=c.resets) for h, c in enumerate(self._humans)]

    # ---- what each human is expected to add -----------------------------------------
    def teleop_gain(self, e: HumanEstimate) -> float:
        """A teleop of t_T steps by ``e``'s human, against the policy on the same arm."""
        policy = self.policy_success() - self.policy_violations()
        pushes = max(self.t_T - e.latency_steps, 0.0)
        return pushes * (e.skill - e.violations) - self.t_T * policy

    def reset_gain(self, e: HumanEstimate) -> float:
        """A hard reset by ``e``'s human: positive, larger for a faster one."""
        return self.t_R / max(e.reset_steps, 1e-9)

    def gains(self, violating: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """(M, N) expected gain of human h on arm i this step: a reset's on a violating
        arm, a teleop's on any other (``Allocator.step``'s ``gains``)."""
        viol = np.asarray(violating, dtype=bool)
        if viol.ndim != 1:
            raise ValueError(f"violating must be (N,), got shape {viol.shape}")
        est = self.estimates()
        teleop = np.array([self.teleop_gain(e) for e in est], dtype=np.float64)
        reset = np.array([self.reset_gain(e) for e in est], dtype=np.float64)
        return np.where(viol[None, :], reset[:, None], teleop[:, None])


def _push(c: _Counts, r: Mapping[str, Any]) -> None:
    c.pushes += 1
    c.successes += bool(r["success"])
    c.violations += bool(r["violation"])
