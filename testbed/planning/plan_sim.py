"""``testbed plan``'s simulation: Algorithm 1 on the fitted processes, many replicates at once.

Why a simulation and not a formula: Algorithm 1's rules (a teleop held t_T steps, a reset
held until done and at least t_R, the top-F candidates to the free humans, a human kept on
their own arm) make queues that no closed form of the fan-out literature follows, and
"how many people for how many arms" is exactly a question about those queues. So the
plan replays, per replicate, one run of T steps of a fleet of N arms and M humans in
which each arm asks for a teleop, violates, succeeds, and each human takes time, by the
processes :mod:`testbed.planning.plan_fit` fitted (no images, no learning), and
allocates every step by Algorithm 1.

The allocation is the real allocator's, vectorised over replicates: :class:`BatchAllocator`
is ``testbed.fleet.allocator.Allocator``'s blind ``step`` (no gains) with a leading
replicate axis, rule for rule (the carry-over, the held interventions, the candidates in
lexicographic key order with the tie draw, the keepers, the rest paired in index order;
with remote humans, only on-site ones reset, candidate by candidate as the allocator).
One ``Allocator.step`` costs ~30 us here; the 3 x 3 grid at 250 steps and 200 replicates
would be ~14 s of it alone, and the plan's budget is 10 s for everything
(``benchmarks/bench_plan.py``). ``tests/testbed/test_plan_sim.py`` holds it to the real
one: equal assignments, kinds and served counts on the same requests (ties included),
and the whole simulation equal with either engine (:class:`RealAllocators`).

What one arm does at step t of a replicate (docs/notes/plan.md says what is assumed):

* violating: its key is the algorithm's ``c`` (eligible from t_I for C.U.R.), else it
  waits (``idle``); a human on it resets it (``reset``), done after the steps drawn for
  that human when the reset started, and never before t_R (the allocator holds it);
* not violating: it is calm or in trouble (:mod:`testbed.planning.plan_trouble`) and
  its key asks for a teleop with that state's rate (a calm arm's by phase); a human on
  it teleoperates, with no push before the latency drawn for that human when the teleop
  started;
* a push (the policy's, or a human's after their latency) succeeds, violates or neither,
  with the policy's rates in the arm's state or the human's own;
* then its state moves: after a human's push it is calm with the fitted chance, after a
  violating step it starts afresh, else a calm arm falls into trouble and a troubled one
  recovers with the fitted rates.

Keys are two columns whose order is the algorithm's (``plan_fit.KeyOrder``); every
candidate carries a fresh uniform draw so no two keys tie and the tie draw never decides
(which is why the two engines agree exactly, whatever their tie streams).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Literal, Protocol

import numpy as np
import numpy.typing as npt

from testbed.fleet.allocator import KIND_NONE, KIND_RESET, KIND_TELEOP, Allocator
from testbed.planning.plan_fit import Draws, KeyOrder
from testbed.records.metrics import rohe

__all__ = ["BatchAllocator", "FleetShape", "RealAllocators", "SimParams", "sim_params",
           "simulate"]

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
FloatArray = npt.NDArray[np.float64]
Engine = Literal["batch", "real"]


class _Allocators(Protocol):
    def step(self, keys: FloatArray, violating: BoolArray, available: BoolArray
             ) -> tuple[IntArray, npt.NDArray[np.int8], IntArray]: ...


def _lex_positive(keys: FloatArray) -> BoolArray:
    """``testbed.fleet.allocator.lex_positive`` over (R, N, K)."""
    first = np.argmax(keys != 0, axis=-1)
    lead = np.take_along_axis(keys, first[..., None], axis=-1)[..., 0]
    return lead > 0


class BatchAllocator:
    """``Allocator`` (blind) for R independent fleets at once: state (R, M) per human.

    ``step`` takes keys (R, N, K), violating (R, N), available (R, M) and optionally the
    tie draw (R, N) (else drawn from its own generator, ``rng.random((R, N))``), and
    returns per arm: human (-1 none), kind code, served, as ``Allocator``'s
    ``assignment``, ``kind_codes``, ``served``. ``on_site`` (M,) as ``Allocator``'s:
    with some humans remote the pairing is the allocator's candidate by candidate
    (:meth:`_pair_allowed`), vectorised over replicates.
    """

    def __init__(self, replicates: int, num_robots: int, num_humans: int,
                 min_teleop_steps: int, hard_reset_steps: int,
                 seed: int | None = None, on_site: npt.ArrayLike | None = None) -> None:
        self.shape: Final = (int(replicates), int(num_robots), int(num_humans))
        self.t_T: Final = int(min_teleop_steps)
        self.t_R: Final = int(hard_reset_steps)
        r, _, m = self.shape
        self.on_site: Final = (np.ones(m, dtype=bool) if on_site is None
                               else np.asarray(on_site, dtype=bool).reshape(m))
        self.arm = np.full((r, m), -1, dtype=np.int64)
        self.kind = np.zeros((r, m), dtype=np.int8)
        self.served = np.zeros((r, m), dtype=np.int64)
        self._rng = np.random.default_rng(seed)

    def _carry_over(self, viol: BoolArray) -> tuple[npt.NDArray[np.int8], IntArray, BoolArray]:
        """``Allocator._carry_over`` per replicate: (kind, served, held) per human."""
        rows = np.arange(self.shape[0])[:, None]
        had = self.arm >= 0
        arm_viol = had & viol[rows, np.maximum(self.arm, 0)]
        served = np.where(had, self.served + 1, 0)
        kind = self.kind.copy()
        convert = had & (kind == KIND_TELEOP) & arm_viol
        kind[convert] = KIND_RESET
        served[convert] = 0
        held = had & (((kind == KIND_TELEOP) & (served < self.t_T))
                      | ((kind == KIND_RESET) & ((served < self.t_R) | arm_viol)
                         & self.on_site))
        return kind, served, held

    def step(self, keys: FloatArray, violating: BoolArray, available: BoolArray,
             tie: FloatArray | None = None) -> tuple[IntArray, npt.NDArray[np.int8], IntArray]:
        r, n, _ = self.shape
        if tie is None:
            tie = self._rng.random((r, n))
        rows = np.arange(r)[:, None]
        kind, served, held = self._carry_over(violating)
        hr, hj = np.nonzero(held)
        arm_held = np.zeros((r, n), dtype=bool)
        arm_held[hr, self.arm[hr, hj]] = True
        free = ~held & available
        new_arm = np.where(held, self.arm, -1)
        new_kind = np.where(held, kind, KIND_NONE).astype(np.int8)
        new_served = np.where(held, served, 0)
        cand = ~arm_held & _lex_positive(keys)
        # Allocator: lexsort(-[tie, key[:, K-1], ..., key[:, 0]]) over the candidates;
        # here over every arm, candidates first (the primary key), stable as there.
        order = np.lexsort((-tie, *(-keys[..., k] for k in reversed(range(keys.shape[-1]))),
                            ~cand), axis=-1)
        rank = np.empty_like(order)
        np.put_along_axis(rank, order, np.arange(n)[None, :].repeat(r, 0), axis=-1)
        chosen = cand & (rank < free.sum(axis=1)[:, None])
        if not self.on_site.all():
            new = (new_arm, new_kind, new_served)
            self._pair_allowed(order, cand, chosen, free, kind, served, violating, new)
            self.arm, self.kind, self.served = new
            return self.per_arm()
        # Keepers: a free human whose last arm is chosen again keeps it.
        keep = free & (self.arm >= 0) & chosen[rows, np.maximum(self.arm, 0)]
        kept_kind = np.where(violating[rows, np.maximum(self.arm, 0)], KIND_RESET,
                             KIND_TELEOP).astype(np.int8)
        new_arm = np.where(keep, self.arm, new_arm)
        new_served = np.where(keep, np.where(kept_kind == kind, served, 0), new_served)
        new_kind = np.where(keep, kept_kind, new_kind).astype(np.int8)
        kr, kj = np.nonzero(keep)
        taken = np.zeros((r, n), dtype=bool)
        taken[kr, self.arm[kr, kj]] = True
        # The rest of the chosen arms, in key order, to the other free humans by index.
        rest = np.take_along_axis(chosen & ~taken, order, axis=-1)
        rest_rank = np.cumsum(rest, axis=-1) - 1
        listed = np.full((r, n), -1, dtype=np.int64)
        rr, cc = np.nonzero(rest)
        listed[rr, rest_rank[rr, cc]] = order[rr, cc]
        others = free & ~keep
        human_rank = np.cumsum(others, axis=-1) - 1
        takes = others & (human_rank < rest.sum(axis=-1)[:, None])
        tr, tj = np.nonzero(takes)
        arms = listed[tr, human_rank[tr, tj]]
        new_arm[tr, tj] = arms
        new_kind[tr, tj] = np.where(violating[tr, arms], KIND_RESET, KIND_TELEOP)
        new_served[tr, tj] = 0
        self.arm, self.kind, self.served = new_arm, new_kind, new_served
        return self.per_arm()

    def _pair_allowed(self, order: IntArray, cand: BoolArray, chosen: BoolArray,
                      free: BoolArray, kind: npt.NDArray[np.int8], served: IntArray,
                      viol: BoolArray,
                      new: tuple[IntArray, npt.NDArray[np.int8], IntArray]) -> None:
        """``Allocator._pair_matched`` with equal gains (some humans remote): position by
        position of the key order, every replicate's candidate there to the free human
        allowed on it that ``Allocator._tie_winner`` picks, as one score per human
        (lowest wins): own arm (when allowed to keep it), remote first for a teleop,
        not a keeper, lowest index."""
        new_arm, new_kind, new_served = new
        r, n, m = self.shape
        rows = np.arange(r)
        on_site = self.on_site[None, :]
        prev = self.arm
        own_arm = np.maximum(prev, 0)
        keeper = (free & (prev >= 0) & chosen[rows[:, None], own_arm]
                  & (on_site | ~viol[rows[:, None], own_arm]))
        ranked_viol = np.take_along_axis(viol & cand, order, axis=-1).astype(np.int64)
        viol_after = np.cumsum(ranked_viol[:, ::-1], axis=-1)[:, ::-1] - ranked_viol
        index = np.arange(m)[None, :]
        left = free.copy()
        for p in range(n):
            arm = order[:, p]
            is_cand = cand[rows, arm]
            if not is_cand.any():
                break  # the candidates come first in every replicate's order
            v = viol[rows, arm]
            allowed = left & (on_site | ~v[:, None]) & is_cand[:, None]
            go = allowed.any(axis=1)
            own = allowed & (prev == arm[:, None])
            spare = (left & on_site).sum(axis=1) - 1 >= viol_after[:, p]
            own_ok = (v | (own & ~on_site).any(axis=1) | ~(allowed & ~on_site).any(axis=1)
                      | spare)
            score = ((~(own & own_ok[:, None])) * 4 * m + (~v[:, None] & on_site) * 2 * m
                     + keeper * m + index)
            j = np.where(allowed, score, np.iinfo(np.int64).max).argmin(axis=1)
            gr, gj, ga = rows[go], j[go], arm[go]
            k = np.where(v[go], KIND_RESET, KIND_TELEOP).astype(np.int8)
            new_arm[gr, gj] = ga
            new_kind[gr, gj] = k
            new_served[gr, gj] = np.where((prev[gr, gj] == ga) & (kind[gr, gj] == k),
                                          served[gr, gj], 0)
            left[gr, gj] = False

    def per_arm(self) -> tuple[IntArray, npt.NDArray[np.int8], IntArray]:
        """(human, kind code, served) per arm (R, N), as ``Allocator``'s queries."""
        r, n, _ = self.shape
        human = np.full((r, n), -1, dtype=np.int64)
        kind = np.zeros((r, n), dtype=np.int8)
        served = np.zeros((r, n), dtype=np.int64)
        br, bj = np.nonzero(self.arm >= 0)
        arms = self.arm[br, bj]
        human[br, arms] = bj
        kind[br, arms] = self.kind[br, bj]
        served[br, arms] = self.served[br, bj]
        return human, kind, served


class RealAllocators:
    """R real ``Allocator``s stepped one after another: the reference engine (slow)."""

    def __init__(self, replicates: int, num_robots: int, num_humans: int,
                 min_teleop_steps: int, hard_reset_steps: int, seed: int | None = None,
                 on_site: npt.ArrayLike | None = None) -> None:
        seeds = np.random.SeedSequence(seed).generate_state(replicates)
        self.allocators = [Allocator(num_robots, num_humans, min_teleop_steps,
                                     hard_reset_steps, seed=int(s), on_site=on_site)
                           for s in seeds]

    def step(self, keys: FloatArray, violating: BoolArray, available: BoolArray
             ) -> tuple[IntArray, npt.NDArray[np.int8], IntArray]:
        out = [(a.step(keys[i], violating[i], available[i]), a.kind_codes, a.served)
               for i, a in enumerate(self.allocators)]
        return (np.stack([o[0] for o in out]), np.stack([o[1] for o in out]),
                np.stack([o[2] for o in out]))


@dataclass(frozen=True)
class FleetShape:
    """What the simulation needs of the algorithm and the rules besides the draws."""

    t_T: int
    t_R: int
    t_I: int
    bin_steps: int
    order: KeyOrder
    initial_period: bool


@dataclass(frozen=True)
class SimParams:
    """The draws with the planned M humans mapped onto the fitted ones: planned human j
    is fitted human j mod H (a lab's k-th person is like its k-th person so far)."""

    draws: Draws
    human: FloatArray
    """(R, M, 3)"""
    available: FloatArray
    """(R, M)"""
    latency_cdf: FloatArray
    """(R, M, S)"""
    reset_cdf: FloatArray
    on_site: BoolArray
    """(M,) the planned humans' places: only those on site reset (``Allocator``)."""


def sim_params(draws: Draws, num_humans: int, on_site: npt.ArrayLike | None = None
               ) -> SimParams:
    """Map the fitted humans onto ``num_humans`` planned ones (:class:`SimParams`);
    ``on_site``: the planned humans' places, (M,) (None: everyone on site)."""
    idx = np.arange(num_humans) % draws.human.shape[1]
    place = (np.ones(num_humans, dtype=bool) if on_site is None
             else np.asarray(on_site, dtype=bool).reshape(num_humans))
    return SimParams(draws, draws.human[:, idx], draws.available[:, idx],
                     draws.latency_cdf[:, idx], draws.reset_cdf[:, idx], place)


def _pick(cdf: FloatArray, values: IntArray, u: FloatArray) -> IntArray:
    """Inverse-CDF draws: ``cdf`` (E, S) per event, ``u`` (E,) uniform."""
    return values[np.minimum((u[:, None] >= cdf).sum(axis=1), values.size - 1)]


@dataclass
class _State:
    """The fleet of every replicate between steps."""

    viol: BoolArray
    kind: npt.NDArray[np.int8]
    served: IntArray
    need: IntArray
    """Per arm: the steps its current intervention's human needs (latency or reset)."""
    trouble: BoolArray
    """Per arm: in trouble (else calm)."""


def simulate(params: SimParams, shape: FleetShape, num_robots: int, num_humans: int,
             steps: int, seed: int | np.random.SeedSequence | None = None,
             engine: Engine = "batch") -> dict[str, FloatArray]:
    """One run of ``steps`` steps per replicate; returns per metric (``plan_fit.METRICS``)
    the (R,) values, each computed as ``plan_fit.run_metrics`` computes a run's."""
    rng = np.random.default_rng(seed)
    r, n, m = params.human.shape[0], num_robots, num_humans
    alloc: _Allocators = (BatchAllocator(r, n, m, shape.t_T, shape.t_R, seed=0,
                                         on_site=params.on_site)
                          if engine == "batch" else
                          RealAllocators(r, n, m, shape.t_T, shape.t_R, seed=0,
                                         on_site=params.on_site))
    state = _State(np.zeros((r, n), bool), np.zeros((r, n), np.int8),
                   np.zeros((r, n), np.int64), np.zeros((r, n), np.int64),
                   rng.random((r, n)) < params.draws.trouble.start[:, None])
    totals = {k: np.zeros(r) for k in ("successes", "hard_resets", "idle_time",
                                        "human_actions", "idle", "requests", "served")}
    for t in range(steps):
        _step(t, params, shape, alloc, state, totals, rng)
    return _metrics(totals, n, m, steps)


def _keys(t: int, params: SimParams, shape: FleetShape, state: _State,
          rng: np.random.Generator) -> tuple[FloatArray, BoolArray]:
    """This step's keys (R, N, 2) and which arms are open teleop requests."""
    d = params.draws
    arm = d.trouble
    r, n = state.viol.shape
    b = min(t // shape.bin_steps, arm.calm_ask.shape[1] - 1)
    p = np.where(state.trouble, arm.trouble_ask[:, None], arm.calm_ask[:, b, None])
    u = rng.random((r, n, 3))
    held = (((state.kind == KIND_TELEOP) & (state.served + 1 < shape.t_T))
            | ((state.kind == KIND_RESET) & ((state.served + 1 < shape.t_R) | state.viol)))
    asks = ~state.viol & (u[..., 0] < p)
    if shape.order == "mixed":
        eligible = state.viol & (u[..., 1] < d.eligible[:, b, None])
    else:
        eligible = state.viol & (not shape.initial_period or t >= shape.t_I)
    x = 1.0 - u[..., 2]  # in (0, 1]: no two candidates tie
    keys = np.zeros((r, n, 2))
    if shape.order == "resets_first":
        keys[..., 0] = np.where(state.viol, np.where(eligible, 1.0, -1.0), 0.0)
        keys[..., 1] = np.where(eligible | asks, x, 0.0)
    elif shape.order == "teleops_first":
        keys[..., 0] = np.where(asks, x, 0.0)
        keys[..., 1] = np.where(eligible, x, 0.0)
    else:
        keys[..., 0] = np.where(eligible | asks, x, 0.0)
    return keys, asks & ~held


def _step(t: int, params: SimParams, shape: FleetShape, alloc: _Allocators, state: _State,
          totals: dict[str, FloatArray], rng: np.random.Generator) -> None:
    """One step of every replicate: keys, Algorithm 1, the humans, the pushes."""
    d = params.draws
    arm = d.trouble
    r, n = state.viol.shape
    b = min(t // shape.bin_steps, arm.calm_ask.shape[1] - 1)
    keys, open_requests = _keys(t, params, shape, state, rng)
    available = rng.random(params.available.shape) < params.available
    human, kind, served = alloc.step(keys, state.viol, available)
    has = human >= 0
    resetting = has & (kind == KIND_RESET)
    teleop = has & (kind == KIND_TELEOP)
    idle = state.viol & ~has
    # A new intervention draws what its human needs: a latency, or a reset's length.
    nr, na = np.nonzero(has & (served == 0))
    if nr.size:
        h = human[nr, na]
        u = rng.random(nr.size)
        is_reset = kind[nr, na] == KIND_RESET
        lat = _pick(params.latency_cdf[nr, h], d.latency_values, u)
        rst = _pick(params.reset_cdf[nr, h], d.reset_values, u)
        state.need[nr, na] = np.where(is_reset, rst, lat)
    pushes = (~state.viol & ~has) | (teleop & (served >= state.need))
    probs = np.where(state.trouble[..., None], arm.trouble_push[:, None, :],
                     arm.calm_push[:, b, None, :])
    tr, ta = np.nonzero(teleop)
    probs[tr, ta] = params.human[tr, human[tr, ta]]
    u = rng.random((r, n))
    success = pushes & (u < probs[..., 0])
    violation = pushes & ~success & (u < probs[..., 0] + probs[..., 1])
    done = resetting & (served + 1 >= state.need)
    # The hidden state moves: afresh after a violating step, fixed by a human's push,
    # else it drifts (plan_trouble's kinds, in the same order).
    v = rng.random((r, n))
    drift = np.where(state.trouble, v >= arm.recover[:, None], v < arm.to_trouble[:, None])
    fixed = v >= arm.fixed[:, None]
    afresh = v < arm.start[:, None]
    human_push = teleop & pushes
    state.trouble = np.where(state.viol, afresh, np.where(human_push, fixed, drift))
    state.viol = (state.viol & ~done) | violation
    state.kind, state.served = kind, served
    totals["successes"] += success.sum(axis=1)
    totals["hard_resets"] += violation.sum(axis=1)
    totals["idle_time"] += (idle | resetting).sum(axis=1)
    totals["human_actions"] += (teleop | resetting).sum(axis=1)
    totals["idle"] += idle.sum(axis=1)
    totals["requests"] += open_requests.sum(axis=1)
    totals["served"] += (open_requests & teleop).sum(axis=1)


def _metrics(totals: dict[str, FloatArray], n: int, m: int, steps: int
             ) -> dict[str, FloatArray]:
    s, a = totals["successes"], totals["human_actions"]
    resets, req = totals["hard_resets"], totals["requests"]
    return {
        "successes": s, "hard_resets": resets, "idle_time": totals["idle_time"],
        "human_actions": a, "rohe": np.array([rohe(x, y, m, n) for x, y in zip(s, a,
                                                                                strict=True)]),
        "utilisation": a / (m * steps) if m else np.zeros_like(a),
        "wait": np.divide(totals["idle"], resets, out=np.zeros_like(s), where=resets > 0),
        "unserved": np.where(req > 0, 1.0 - np.divide(totals["served"], req,
                                                      out=np.zeros_like(s), where=req > 0),
                             0.0),
    }
