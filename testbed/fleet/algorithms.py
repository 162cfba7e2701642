"""The registry of allocation algorithms, by name: spec, priority factory, flags.

Why apart from the priority functions: an algorithm is a name, a priority function, two
flags (does the policy learn, may humans teleoperate) and what it reads; the command
line, protocols, sweeps and the trial pick one with ``get_algorithm(name, ...)``. New
keys go in :mod:`testbed.fleet.priorities`; a new named algorithm (or ablation) here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.allocator import Allocator
from testbed.fleet.monitor_priority import MONITOR_READS, MonitorPriority
from testbed.fleet.priorities import (
    CRITIC_OF_SIGNAL,
    LEARNED_SIGNALS,
    FloatArray,
    OrderedPriority,
    PriorityFunction,
    PrioritySignals,
    RandomPriority,
    ThriftyPriority,
)
from testbed.monitor.failure_head import FailureHead
from testbed.monitor.monitor_config import MonitorConfig

__all__ = ["ABLATIONS", "ALGORITHMS", "ALGORITHM_NAMES", "Algorithm", "AlgorithmSpec",
           "get_algorithm"]


PriorityFactory = Callable[[AlgorithmConfig, int, int, np.random.SeedSequence, Allocator,
                            MonitorConfig],
                           PriorityFunction]


@dataclass(frozen=True, slots=True)
class AlgorithmSpec:
    """One named algorithm: how to build its priority function, and its two flags.

    What it reads and trains is derived from its factory's ``reads`` (the priority
    class's own declaration); a factory without one is taken to read every signal.
    """

    name: str
    priority: PriorityFactory = field(repr=False)
    learns: bool = True
    """Human labels are added to the data and the policy trains online (BC: False)."""
    teleop: bool = True
    """Humans may teleoperate (BC: False; its keys only ever pick violating arms)."""
    description: str = ""

    @property
    def reads(self) -> frozenset[str]:
        """The learned signals its keys read (subset of ``LEARNED_SIGNALS``)."""
        declared = getattr(self.priority, "reads", None)
        return LEARNED_SIGNALS if declared is None else frozenset(declared)

    @property
    def critics(self) -> frozenset[str]:
        """The critics behind what it reads: ``"safety"`` (risk), ``"goal"`` (goal_risk)."""
        return frozenset(CRITIC_OF_SIGNAL[s] for s in self.reads if s in CRITIC_OF_SIGNAL)

    @property
    def train_parts(self) -> frozenset[str]:
        """What the learner trains online for it: the policy and the critics it reads,
        or nothing for an algorithm that does not learn (BC)."""
        return frozenset({"policy", *self.critics}) if self.learns else frozenset()


@dataclass(slots=True)
class Algorithm:
    """A ready-to-run algorithm: its spec, priority function and its own allocator.

    Use :meth:`step` (keys then allocation) so that priority functions that look at
    the allocator (Random) see the same allocator that allocates.
    """

    spec: AlgorithmSpec
    priority: PriorityFunction
    allocator: Allocator
    params: AlgorithmConfig
    last_keys: FloatArray | None = None

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def names(self) -> tuple[str, ...]:
        return self.priority.names

    @property
    def learns(self) -> bool:
        return self.spec.learns

    @property
    def teleop(self) -> bool:
        return self.spec.teleop

    @property
    def matched(self) -> bool:
        """``algorithm.operators = "matched"``: the caller hands :meth:`step` the
        humans' expected gains (``testbed.fleet.operators.OperatorModel.gains``)."""
        return self.params.operators == "matched"

    def step(self, signals: PrioritySignals,
             gains: npt.ArrayLike | None = None) -> npt.NDArray[np.int64]:
        """Compute the keys and allocate; returns (N,) human per arm, -1 for none.

        ``gains``: (M, N) per human and arm, for the matched pairing (the keys are
        computed first either way: it works with every priority function); ``None``:
        Algorithm 1. Refused when the config says ``operators = "blind"``, so a blind
        run can never be matched by accident.
        """
        if gains is not None and not self.matched:
            raise ValueError('gains given to an algorithm with operators = "blind"')
        keys = self.priority.keys(signals)
        available = (None if signals.available is None
                     else signals.available_array(self.allocator.num_humans))
        assignment = self.allocator.step(
            keys, signals.violating_array(self.allocator.num_robots), available, gains)
        self.last_keys = keys
        return assignment

    def row_fields(self, robot: int) -> dict[str, float]:
        """What the row's ``monitor`` keeps of the priority's own state for an arm (the
        monitor algorithm's alarm: its score and threshold); {} for the others."""
        fields = getattr(self.priority, "row_fields", None)
        return fields(robot) if callable(fields) else {}

    def observe(self, frames: np.ndarray) -> None:
        """The step's frames, to a priority function that learns from how episodes end
        (the monitor's alarm); nothing for the others."""
        see = getattr(self.priority, "observe", None)
        if callable(see):
            see(frames)

    def reason(self, robot: int) -> dict[str, float]:
        """The named key entries of arm ``robot`` at the last step (``HumanRequest.reason``)."""
        if self.last_keys is None:
            return {}
        return {n: float(v) for n, v in zip(self.names, self.last_keys[robot], strict=True)}

    def state_dict(self) -> dict[str, Any]:
        return {"name": self.name, "allocator": self.allocator.state_dict(),
                "priority": self.priority.state_dict(),
                "last_keys": None if self.last_keys is None else self.last_keys.tolist()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state.get("name") != self.name:
            raise ValueError(f"state is for algorithm {state.get('name')!r}, not {self.name!r}")
        self.allocator.load_state_dict(state["allocator"])
        self.priority.load_state_dict(state["priority"])
        lk = state.get("last_keys")
        self.last_keys = None if lk is None else np.asarray(lk, dtype=np.float64)


def _reading(reads: frozenset[str]) -> Callable[[PriorityFactory], PriorityFactory]:
    """Mark a factory with what its priority function reads (``AlgorithmSpec.reads``)."""
    def mark(factory: PriorityFactory) -> PriorityFactory:
        factory.reads = reads  # type: ignore[attr-defined]
        return factory
    return mark


def _ordered(order: str, *, initial_period: bool) -> PriorityFactory:
    @_reading(OrderedPriority.reads_of(order))
    def build(p: AlgorithmConfig, n: int, m: int, seed: np.random.SeedSequence,
              allocator: Allocator, monitor: MonitorConfig) -> PriorityFunction:
        del m, seed, allocator, monitor
        if isinstance(p.u_hat, str) or isinstance(p.r_hat, str):
            raise ValueError("u_hat / r_hat given as quantiles are resolved on theta_0 by "
                             "the trial (testbed/fleet/thresholds.py) before the algorithm is "
                             "built")
        return OrderedPriority(order, n, initial_period=p.t_I if initial_period else 0,
                               u_hat=p.u_hat, r_hat=p.r_hat)
    return build


@_reading(ThriftyPriority.reads)
def _thrifty(p: AlgorithmConfig, n: int, m: int, seed: np.random.SeedSequence,
             allocator: Allocator, monitor: MonitorConfig) -> PriorityFunction:
    del m, seed, allocator, monitor
    return ThriftyPriority(n, alpha=p.thrifty_alpha, threshold=p.thrifty_threshold)


@_reading(RandomPriority.reads)
def _random(p: AlgorithmConfig, n: int, m: int, seed: np.random.SeedSequence,
            allocator: Allocator, monitor: MonitorConfig) -> PriorityFunction:
    del monitor
    if isinstance(p.random_budget, str):  # a protocol resolves it before the run starts
        raise ValueError(f"random_budget = {p.random_budget!r} is resolved by a protocol "
                         "from the matched algorithm's run; give a number for a trial alone")
    return RandomPriority(n, m, budget=p.random_budget, seed=seed, allocator=allocator)


@_reading(MONITOR_READS)
def _monitor(p: AlgorithmConfig, n: int, m: int, seed: np.random.SeedSequence,
             allocator: Allocator, monitor: MonitorConfig) -> PriorityFunction:
    del m, seed, allocator
    if isinstance(p.u_hat, str) or isinstance(p.r_hat, str):
        raise ValueError("u_hat / r_hat given as quantiles are resolved on theta_0 by "
                         "the trial (testbed/fleet/thresholds.py) before the algorithm is "
                         "built")
    head = FailureHead.load(monitor.head) if monitor.head is not None else None
    return MonitorPriority(n, score=monitor.score, alpha=monitor.alpha, window=monitor.window,
                           u_hat=p.u_hat, r_hat=p.r_hat, head=head, alarm=monitor.alarm,
                           gamma=monitor.gamma)


ABLATIONS: Final = ("c", "u", "r", "cu", "cr", "ur", "uc", "ru", "cru")

ALGORITHMS: Final[dict[str, AlgorithmSpec]] = {
    "bc": AlgorithmSpec("bc", _ordered("c", initial_period=False), learns=False, teleop=False,
                        description="behaviour cloning: hard resets only, no learning"),
    "random": AlgorithmSpec("random", _random,
                            description="random arms at a human-effort budget"),
    "fleet-ed": AlgorithmSpec("fleet-ed", _ordered("uc", initial_period=False),
                              description="Fleet-EnsembleDAgger: (u, c)"),
    "fleet-td": AlgorithmSpec("fleet-td", _thrifty,
                              description="Fleet-ThriftyDAgger: (thrifty score, c)"),
    "cur": AlgorithmSpec("cur", _ordered("cur", initial_period=True),
                         description="C.U.R.: (c, u, r) with the initial period t_I"),
    "monitor": AlgorithmSpec("monitor", _monitor,
                             description="the failure monitor: a person where the calibrated "
                             "alarm fires, most likely failure first ([monitor])"),
    "cur-i": AlgorithmSpec("cur-i", _ordered("cur", initial_period=False),
                           description="C.U.R.(-i): no initial period"),
    **{a: AlgorithmSpec(a, _ordered(a, initial_period=False),
                        description=f"ablation: ({', '.join(a)}), no initial period")
       for a in ABLATIONS},
}
ALGORITHM_NAMES: Final[tuple[str, ...]] = tuple(ALGORITHMS)


def get_algorithm(name: str, params: AlgorithmConfig, num_robots: int, num_humans: int,
                  seed: int | None, monitor: MonitorConfig | None = None, *,
                  on_site: Sequence[bool] | None = None) -> Algorithm:
    """Build the algorithm ``name`` (its priority function and allocator) for a fleet.

    ``seed`` seeds both the allocator's tie-breaks and the priority's own randomness
    (independent streams). ``on_site``: per human, in the room with the arms (the
    config's ``humans.on_site``; None: everyone), the allocator's mask: only those are
    given hard resets. Unknown names raise ``ValueError`` listing the valid ones.
    """
    spec = ALGORITHMS.get(name.strip().lower()) if isinstance(name, str) else None
    if spec is None:
        raise ValueError(f"unknown algorithm {name!r}; valid names: "
                         f"{', '.join(ALGORITHM_NAMES)}")
    alloc_seed, prio_seed = np.random.SeedSequence(seed).spawn(2)
    allocator = Allocator(num_robots, num_humans, params.t_T, params.t_R,
                          seed=int(alloc_seed.generate_state(1, np.uint64)[0]),
                          on_site=None if on_site is None else np.array(on_site, dtype=bool))
    priority = spec.priority(params, num_robots, num_humans, prio_seed, allocator,
                             monitor or MonitorConfig())
    return Algorithm(spec=spec, priority=priority, allocator=allocator, params=params)
