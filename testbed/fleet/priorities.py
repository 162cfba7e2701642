"""Priority functions: the keys that decide which arm gets a human.

Why this module exists: in Fleet-DAgger an algorithm *is* a priority function (plus
two flags: does the policy learn, may humans teleoperate). The allocator is shared
(:mod:`testbed.fleet.allocator`), so everything that distinguishes BC, Random, Fleet-ED,
Fleet-TD, C.U.R. and the paper's ablations (appendix 8.4, figure 6) lives here; the
registry that names them (``get_algorithm(name, ...)``) is :mod:`testbed.fleet.algorithms`.

::

    learner.act ─► PrioritySignals(t, violating, uncertainty, risk, goal_risk, novelty,
                   faulted, available, waited)
                                   │
                   Algorithm.priority.keys(signals) ─► keys (N, K), names[K]
                                   │
                   Algorithm.allocator.step(keys, violating, available) ─► human per arm

A key is compared lexicographically, larger first; only keys > 0 (first non-zero entry
positive) can receive a new human (docs/notes/core.md, "Allocation rules"). ``names``
labels the entries so the console can say why an arm was chosen (``reason``).

The keys per algorithm (``c`` = 1 if the arm is violating):

=============  ===========================================================
``cur``        (c, u, r); c = -1 instead of 1 while t < t_I (initial period)
``cur-i``      (c, u, r) without the initial period
ablations      ``c u r cu cr ur uc ru cru``: those entries in that order, no t_I
``fleet-ed``   (u, c)  -- Fleet-EnsembleDAgger
``fleet-td``   (s, c)  -- Fleet-ThriftyDAgger; s = thrifty score margin
``random``     (c, x)  -- random arms, sized to a human-effort budget
``bc``         (c,)    -- hard resets only; no teleop, no learning
``monitor``    (c, a, s, u, r) -- the failure monitor (``monitor_priority.py``): a = its
               calibrated alarm fired, s = the score; C.U.R.'s u, r until it is ready
=============  ===========================================================

u = uncertainty if uncertainty >= u_hat else 0; r = risk if risk >= r_hat else 0.

Decisions beyond the paper's text (also in docs/notes/core.md):

* During C.U.R.'s initial period a violating arm's key starts with -1, so by the
  contract's eligibility rule it gets no human at all until t_I (the paper's code let
  such an arm through behind all others when its u or r was positive).
* Fleet-TD follows the paper's code: key (s, c). s = z - threshold where
  z = alpha * z(goal_risk) + (1 - alpha) * z(novelty) exceeds ``thrifty_threshold``,
  else 0; z() standardises with running (Welford) mean and std over every value seen
  so far, this step's included. Violating arms come after every arm above the
  threshold, but still get their reset. (s is the margin, not z itself, so a
  negative threshold still makes "above threshold" mean "eligible".)
* Random keeps the paper's scheme (busy humans drawn per step, the held ones kept,
  violating arms first, then arms at random) but draws the count with feedback on the
  effort used so far: busy ~ Binomial(M, clip(deficit / M, 0, 1)), deficit = the
  budget ``random_budget * M * steps`` minus the human-steps spent, so the
  cumulative human effort tracks the budget even though teleops are held t_T steps.
* Arms marked ``faulted`` (host unreachable) get an all-zero key: never a new human.
* Humans not ``available`` (away from the web console) are never newly assigned (the
  allocator's rule); Random sizes its new arms to the free humans who are present, so
  its effort count never includes arms no one could take.
* ``waited`` (how long each arm has waited for a human, ``Allocator.waited``) is not
  learned: the loop hands it to every priority function, and none of the paper's reads
  it. A priority that ranks by it is a class here and a registry entry
  (``tests/testbed/test_wait_signal.py`` adds one, "d", in a test).

What an algorithm reads decides what the learner trains (issue 13): each priority class
declares the learned signals its keys read (``reads``: a subset of uncertainty, risk,
goal_risk, novelty), its registry factory carries the same set, and
``AlgorithmSpec.critics`` maps it to the critics behind it (risk -> the safety critic,
goal_risk -> the goal critic). The trial trains online, and ``act`` computes, only those
(``AlgorithmSpec.train_parts``); a test checks that every algorithm's keys work with
exactly the signals it declares.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from testbed.fleet.allocator import Allocator, rng_from_state, rng_state_json

__all__ = [
    "CRITIC_OF_SIGNAL",
    "LEARNED_SIGNALS",
    "OrderedPriority",
    "PriorityFunction",
    "PrioritySignals",
    "RandomPriority",
    "RunningStats",
    "ThriftyPriority",
]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

LEARNED_SIGNALS: Final = frozenset({"uncertainty", "risk", "goal_risk", "novelty", "ood"})
"""The signals that come from the learner (``violating`` comes from the arms)."""

CRITIC_OF_SIGNAL: Final[dict[str, str]] = {"risk": "safety", "goal_risk": "goal"}
"""Which critic a signal comes from; uncertainty and novelty come from the policy."""


@dataclass(frozen=True, slots=True)
class PrioritySignals:
    """Per-arm signals at timestep ``t``; every array is (N,).

    A signal an algorithm does not use may be ``None``; one it needs raises
    ``ValueError``. Faulted arms may carry any finite placeholder (0): their keys are
    zeroed. NaN is refused.
    """

    t: int
    violating: npt.ArrayLike
    uncertainty: npt.ArrayLike | None = None
    """Ensemble disagreement of the policy (Fleet-ED, C.U.R.'s u)."""
    risk: npt.ArrayLike | None = None
    """Safety-critic estimate of a future constraint violation (C.U.R.'s r)."""
    goal_risk: npt.ArrayLike | None = None
    """1 - goal-critic value (Fleet-TD's risk)."""
    novelty: npt.ArrayLike | None = None
    """Fleet-TD's novelty."""
    ood: npt.ArrayLike | None = None
    """The distance to the policy's training data in its own feature space (the failure
    monitor's; ``testbed/learning/features.py``)."""
    features: npt.ArrayLike | None = None
    """Float (N, D): the policy's trunk features of each arm's image (``PolicyOutput.
    features``), what the failure monitor's head reads; not a signal of its own."""
    faulted: npt.ArrayLike | None = None
    """Bool (N,): the arm's host is unreachable this step (``None``: none are)."""
    available: npt.ArrayLike | None = None
    """Bool (M,), per human: present this step (``None``: all are). Away humans (web
    console) get no new intervention (``Allocator.step``'s ``available``)."""
    waited: npt.ArrayLike | None = None
    """Int (N,): the steps each arm has waited for a human so far, up to the last step
    (``Allocator.waited`` before this step's allocation; 0: not waiting), so a priority
    may put the longest wait first. Not learned: it comes from the allocator."""

    def violating_array(self, n: int) -> BoolArray:
        return self._mask("violating", n, None)

    def faulted_array(self, n: int) -> BoolArray:
        return self._mask("faulted", n, False)

    def available_array(self, m: int) -> BoolArray:
        """The (m,) mask of present humans, checked; all True when ``available`` is None."""
        return self._mask("available", m, True)

    def _mask(self, name: str, size: int, default: bool | None) -> BoolArray:
        """Field ``name`` as a checked bool (size,) array; ``default`` fills a None."""
        value = getattr(self, name)
        if value is None and default is not None:
            return np.full(size, default, dtype=bool)
        arr = np.asarray(value)
        if arr.dtype != np.bool_ or arr.shape != (size,):
            raise ValueError(f"signals.{name} must be bool with shape ({size},), "
                             f"got {arr.dtype} {arr.shape}")
        return arr

    def waited_array(self, n: int) -> npt.NDArray[np.int64]:
        """``waited`` as (n,) ints >= 0, checked; all 0 when it is None (no wait known)."""
        if self.waited is None:
            return np.zeros(n, dtype=np.int64)
        arr = np.asarray(self.waited)
        if (arr.shape != (n,) or not np.issubdtype(arr.dtype, np.integer)
                or (arr < 0).any()):
            raise ValueError(f"signals.waited must be ints >= 0 with shape ({n},), "
                             f"got {arr.dtype} {arr.shape}")
        return arr.astype(np.int64)

    def features_array(self, n: int) -> FloatArray:
        """``features`` as (n, D), checked: present, n rows, no NaN."""
        if self.features is None:
            raise ValueError("signals.features is required by this priority function")
        arr = np.asarray(self.features, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[0] != n:
            raise ValueError(f"signals.features must have shape ({n}, D), got {arr.shape}")
        if np.isnan(arr).any():
            raise ValueError("signals.features has NaN")
        return arr

    def signal(self, name: str, n: int) -> FloatArray:
        """The float signal ``name`` as (n,), checked: present, right shape, no NaN."""
        value = getattr(self, name)
        if value is None:
            raise ValueError(f"signals.{name} is required by this priority function")
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"signals.{name} must be numeric: {exc}") from None
        if arr.shape != (n,):
            raise ValueError(f"signals.{name} must have shape ({n},), got {arr.shape}")
        if np.isnan(arr).any():
            raise ValueError(f"signals.{name} has NaN for arm(s) "
                             f"{np.flatnonzero(np.isnan(arr)).tolist()}")
        return arr


@runtime_checkable
class PriorityFunction(Protocol):
    """Maps per-arm signals to lexicographic keys (N, K)."""

    names: tuple[str, ...]

    def keys(self, s: PrioritySignals) -> FloatArray: ...

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: dict[str, Any]) -> None: ...


def check_t(t: int) -> int:
    if isinstance(t, bool) or not isinstance(t, int | np.integer):
        raise ValueError(f"signals.t must be an int, got {t!r}")
    return int(t)


class OrderedPriority:
    """C.U.R., its ablations, Fleet-ED and BC: a tuple of c, u, r in a given order.

    ``order`` is a string over ``"cur"`` (``"uc"`` is Fleet-ED, ``"c"`` is BC).
    ``initial_period`` t_I: for t < t_I a violating arm's c is -1 instead of 1.
    """

    SIGNAL_OF_LETTER: Final = {"u": "uncertainty", "r": "risk"}

    @classmethod
    def reads_of(cls, order: str) -> frozenset[str]:
        """The learned signals the keys of ``order`` read (``c`` reads none)."""
        return frozenset(cls.SIGNAL_OF_LETTER[x] for x in order if x in cls.SIGNAL_OF_LETTER)

    def __init__(self, order: str, num_robots: int, *, initial_period: int = 0,
                 u_hat: float = 0.0, r_hat: float = 0.0) -> None:
        if not order or set(order) - set("cur") or len(set(order)) != len(order):
            raise ValueError(f"order must be distinct letters of 'cur', got {order!r}")
        self.reads: frozenset[str] = self.reads_of(order)
        if initial_period < 0:
            raise ValueError(f"initial_period must be >= 0, got {initial_period}")
        self.order: Final[str] = order
        self.names: tuple[str, ...] = tuple(order)
        self.num_robots: Final[int] = num_robots
        self.initial_period: Final[int] = int(initial_period)
        self.u_hat: Final[float] = float(u_hat)
        self.r_hat: Final[float] = float(r_hat)

    def keys(self, s: PrioritySignals) -> FloatArray:
        n = self.num_robots
        t = check_t(s.t)
        viol = s.violating_array(n)
        cols: list[FloatArray] = []
        for letter in self.order:
            if letter == "c":
                c_value = -1.0 if t < self.initial_period else 1.0
                cols.append(np.where(viol, c_value, 0.0))
            elif letter == "u":
                u = s.signal("uncertainty", n)
                cols.append(np.where(u >= self.u_hat, u, 0.0))
            else:
                r = s.signal("risk", n)
                cols.append(np.where(r >= self.r_hat, r, 0.0))
        keys = np.stack(cols, axis=1)
        keys[s.faulted_array(n)] = 0.0
        return keys

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        del state  # stateless


class RunningStats:
    """Welford/Chan running mean and (population) variance over batches of values."""

    def __init__(self) -> None:
        self.count = 0
        self.mean = 0.0
        self.m2 = 0.0

    def update(self, values: FloatArray) -> None:
        k = int(values.size)
        if k == 0:
            return
        b_mean = float(values.mean())
        b_m2 = float(((values - b_mean) ** 2).sum())
        total = self.count + k
        delta = b_mean - self.mean
        self.mean += delta * k / total
        self.m2 += b_m2 + delta * delta * self.count * k / total
        self.count = total

    @property
    def std(self) -> float:
        return float(np.sqrt(self.m2 / self.count)) if self.count else 0.0

    def standardise(self, values: FloatArray, eps: float = 1e-8) -> FloatArray:
        return (values - self.mean) / (self.std + eps)

    def state_dict(self) -> dict[str, Any]:
        return {"count": self.count, "mean": self.mean, "m2": self.m2}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.count = int(state["count"])
        self.mean = float(state["mean"])
        self.m2 = float(state["m2"])


class ThriftyPriority:
    """Fleet-ThriftyDAgger: key (s, c), s = margin of the thrifty score over a threshold.

    score = alpha * z(goal_risk) + (1 - alpha) * z(novelty), standardised by running
    statistics that include this step's (non-faulted) values, as the paper's code does.
    """

    names: tuple[str, ...] = ("s", "c")
    reads: frozenset[str] = frozenset({"goal_risk", "novelty"})

    def __init__(self, num_robots: int, *, alpha: float = 0.5, threshold: float = 0.0,
                 eps: float = 1e-8) -> None:
        if not 0.0 <= alpha <= 1.0:
            raise ValueError(f"alpha must be in [0, 1], got {alpha}")
        self.num_robots: Final[int] = num_robots
        self.alpha: Final[float] = float(alpha)
        self.threshold: Final[float] = float(threshold)
        self.eps: Final[float] = float(eps)
        self.risk_stats = RunningStats()
        self.novelty_stats = RunningStats()

    def scores(self, s: PrioritySignals, *, update: bool = True) -> FloatArray:
        """The raw thrifty score per arm (updating the running statistics first)."""
        n = self.num_robots
        risk = s.signal("goal_risk", n)
        novelty = s.signal("novelty", n)
        ok = ~s.faulted_array(n)
        if update:
            self.risk_stats.update(risk[ok])
            self.novelty_stats.update(novelty[ok])
        return (self.alpha * self.risk_stats.standardise(risk, self.eps)
                + (1.0 - self.alpha) * self.novelty_stats.standardise(novelty, self.eps))

    def keys(self, s: PrioritySignals) -> FloatArray:
        n = self.num_robots
        check_t(s.t)
        viol = s.violating_array(n)
        score = self.scores(s)
        margin = np.where(score > self.threshold, score - self.threshold, 0.0)
        keys = np.stack([margin, viol.astype(np.float64)], axis=1)
        keys[s.faulted_array(n)] = 0.0
        return keys

    def state_dict(self) -> dict[str, Any]:
        return {"risk": self.risk_stats.state_dict(),
                "novelty": self.novelty_stats.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.risk_stats.load_state_dict(state["risk"])
        self.novelty_stats.load_state_dict(state["novelty"])


class RandomPriority:
    """The Random baseline: random arms get humans, at a budgeted human effort.

    Each step it draws how many humans should be busy, keeps the held ones (they must
    stay), and makes exactly ``busy - held`` other arms eligible: violating arms first
    (their resets are due), then arms at random. Key (c, x): c = 1 for a chosen
    violating arm, x in (0, 1] for every chosen arm, (0, 0) otherwise.

    It needs the allocator's held set to size the draw; :func:`get_algorithm` binds it,
    and the bound allocator must be the one that allocates, once after each
    :meth:`keys` (checked: ``RuntimeError`` otherwise). Unbound, it assumes nobody is
    held.

    Away humans (``signals.available``): the new arms are at most the free humans who
    are present, so an arm made eligible always gets a human and ``effort`` counts only
    human-steps that happen; the budget's deficit then catches up when they are back.
    With every human present the cap is M - held, never binding: the draws and keys
    are those of a run without the mask. Remote humans (``Allocator.on_site``): the
    violating arms made eligible are at most the free on-site people who are present
    (only they reset), so again every eligible arm gets a human; everyone on site, the
    cap never binds.
    """

    names: tuple[str, ...] = ("c", "x")
    reads: frozenset[str] = frozenset()

    def __init__(self, num_robots: int, num_humans: int, *, budget: float,
                 seed: int | np.random.SeedSequence | None = None,
                 allocator: Allocator | None = None) -> None:
        if not 0.0 <= budget <= 1.0:
            raise ValueError(f"budget must be in [0, 1], got {budget}")
        self.num_robots: Final[int] = num_robots
        self.num_humans: Final[int] = num_humans
        self.budget: Final[float] = float(budget)
        self.allocator = allocator
        self._rng = np.random.default_rng(seed)
        self.steps = 0
        self.effort = 0
        """Human-steps spent so far (busy humans summed over steps)."""

    def keys(self, s: PrioritySignals) -> FloatArray:
        n, m = self.num_robots, self.num_humans
        check_t(s.t)
        viol = s.violating_array(n)
        faulted = s.faulted_array(n)
        present = s.available_array(m)
        if self.allocator is not None and self.allocator.steps != self.steps:
            raise RuntimeError(
                "RandomPriority: its allocator has stepped "
                f"{self.allocator.steps} times but keys() ran {self.steps} times; allocate "
                "with the algorithm's own allocator (Algorithm.allocator or Algorithm.step), "
                "once per keys() call, or the human-effort budget cannot be kept")
        held = (self.allocator.held_mask(viol) if self.allocator is not None
                else np.zeros(n, dtype=bool))
        num_held = int(held.sum())
        held_humans = (self.allocator.held_humans(viol) if self.allocator is not None
                       else np.zeros(m, dtype=bool))
        free_present = int(np.count_nonzero(present & ~held_humans))
        on_site = (self.allocator.on_site if self.allocator is not None
                   else np.ones(m, dtype=bool))
        free_on_site = int(np.count_nonzero(present & ~held_humans & on_site))

        self.steps += 1
        deficit = self.budget * m * self.steps - self.effort
        p = min(max(deficit / m, 0.0), 1.0) if m else 0.0
        busy = max(int(self._rng.binomial(m, p)), num_held)
        # Drawn every step, so the stream does not depend on the signals.
        order = self._rng.permutation(n)
        x = 1.0 - self._rng.random(n)  # in (0, 1]

        open_arms = ~held & ~faulted
        ranked = order[open_arms[order]]
        count = min(max(busy - num_held, 0), free_present)
        # Violating arms first, as many as there are free on-site people to reset them
        # (all of the count when everyone is on site: the paper's scheme), then others.
        resets = ranked[viol[ranked]][: min(count, free_on_site)]
        chosen = np.concatenate([resets, ranked[~viol[ranked]][: count - resets.size]])
        self.effort += num_held + chosen.size

        keys = np.zeros((n, 2), dtype=np.float64)
        keys[chosen, 0] = viol[chosen].astype(np.float64)
        keys[chosen, 1] = x[chosen]
        return keys

    def state_dict(self) -> dict[str, Any]:
        return {"steps": self.steps, "effort": self.effort, "rng": rng_state_json(self._rng)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self._rng = rng_from_state(state["rng"])
        self.steps = int(state["steps"])
        self.effort = int(state["effort"])
