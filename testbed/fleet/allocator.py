"""Which arm gets which human this timestep: Algorithm 1 of Fleet-DAgger, vectorised.

Why this module exists: the allocation policy is the part of interactive fleet learning
that turns "which robots need help most" (the priority keys) into "who helps whom",
while honouring the two physical facts the priority function cannot see: a human who
starts teleoperating stays long enough for the data to be useful (t_T), and a hard
reset takes real time and cannot be abandoned while the cube is still out (t_R). Every
algorithm of the testbed (BC, Random, Fleet-ED, Fleet-TD, C.U.R. and the ablations)
shares this one allocator and differs only in its keys, so the comparison between
algorithms is about priorities, not about bookkeeping.

One step (docs/notes/core.md, "Allocation rules")::

    humans' state at t-1 (arm, kind, served)     keys (N, K), violating (N,), available (M,)
          │                                                 │
          ▼                                                 │
    served += 1; teleop on a violating arm ─► reset, served = 0
          │        (a remote human's: ended, the human free)│
    held = teleop & served < t_T                            │
         | reset  & (served < t_R | arm violating)          │
          │                                                 ▼
          ├──► held humans stay (away or not) ─┐  candidates = not held & key >lex 0
          │                                    │  lexsort by key (desc), seeded random ties
          ├──► free, away humans ──► no arm    │  (their arms are candidates again)
          │                                    │
          └──► free, available humans ──► top-F candidates (F = their number; one whose
                                arm is among them keeps it; the rest pair up in order)
                                (some humans remote: each candidate in key order to a
                                free human allowed on it; a violating arm on-site only)
                                               ▼
                      assignment (N,): human index or -1;  kinds / served per arm

``available`` (optional, bool (M,)) says which humans are present this step (the web
console's away humans, docs/notes/web.md). An away human is never newly assigned and
does not keep an arm it is no longer held on; a *held* intervention of an away human
goes on, because ending it is the console's call (its grace period): the fleet loop
then frees that human with :meth:`Allocator.release_human`. Without the mask every
human is available, exactly as before the mask existed (same RNG stream, same records).

``on_site`` (optional, bool (M,), a constructor argument: the config's
``humans.people[].where``) says who is in the room with the arms. Only an on-site human
is given a violating arm (a hard reset is hands on the cube); a remote human's teleop
on an arm that becomes violating is not converted to a reset: the human is free, and
the arm is a candidate for an on-site human (it waits while none is free). With some
humans remote the pairing is :meth:`Allocator._pair_matched`'s with equal gains (each
candidate in key order to a free human allowed on it; a candidate nobody free may take
is passed over, so the next one can use the human; a teleop prefers a free remote
human, keeping the on-site people for resets). Without the mask, or with everyone on
site, Algorithm 1 exactly as before (same RNG stream, same records). It is
configuration, not state: :meth:`Allocator.state_dict` does not keep it.

``served`` counts the earlier consecutive timesteps a human has spent on the current
intervention; it starts at 0 on the first timestep. A kind change restarts it: the
contract's teleop-to-reset conversion, and (our decision) a finished reset whose arm
is chosen again for teleoperation, so that the new teleop is held its full t_T.

``waited`` is ``served``'s other side, per arm: how many consecutive timesteps the arm
has waited for a human, the last one included (1 on a wait's first step, 0 when it
does not wait). An arm waits at a step when it ends the allocation with no human and
either violates (idle until a reset) or has a key > 0 (the priority asked for a human
and none was free: queued). A faulted arm has an all-zero key and is not violating
to the allocator, so it does not wait; a fault ends a wait. The count is kept here,
where the allocation is decided, so that the priority functions (the next step's
``PrioritySignals.waited``), the rows (``"waited"``), a resume (``state_dict``) and the
consoles all read the one number; it never changes an allocation by itself.

``gains`` (optional, float (M, N): human h's expected gain on arm i this step, from
``testbed.fleet.operators.OperatorModel``) turns on the matched pairing
(``algorithm.operators = "matched"``): the candidates in key order each go to the free
human with the highest gain on it, and a teleop candidate that every free human is
expected to do worse on than the policy stays autonomous (:meth:`Allocator._pair_matched`).
Everything before the pairing (held interventions, away humans, the candidates, their
order, the tie draw) is the same; with equal gains for every human the pairing is
Algorithm 1's, arm for arm. Without ``gains``, Algorithm 1 exactly as before.

Tie-breaking draws ``rng.random(N)`` once per step (always, so the stream does not
depend on the keys); among equal keys the larger draw goes first. The state, RNG
included, round-trips through JSON (``state_dict``) so a crashed trial resumes with
the same future allocations.

Over 450 lines, on purpose: Algorithm 1's allocation is one state machine (who serves
whom, for how long, released when); ``testbed/planning/plan_sim.py::BatchAllocator``
must follow it, and reads it whole.
"""

from __future__ import annotations

from typing import Any, Final

import numpy as np
import numpy.typing as npt

from testbed.core.types import InterventionKind

__all__ = [
    "KIND_NONE",
    "KIND_RESET",
    "KIND_TELEOP",
    "Allocator",
    "lex_positive",
    "rng_from_state",
    "rng_state_json",
]

KIND_NONE: Final = 0
KIND_TELEOP: Final = 1
KIND_RESET: Final = 2
_KIND_TO_ENUM: Final[dict[int, InterventionKind | None]] = {
    KIND_NONE: None,
    KIND_TELEOP: InterventionKind.TELEOP,
    KIND_RESET: InterventionKind.RESET,
}
_KIND_TO_STR: Final[dict[int, str | None]] = {
    KIND_NONE: None,
    KIND_TELEOP: "teleop",
    KIND_RESET: "reset",
}
_STR_TO_KIND: Final[dict[str | None, int]] = {v: k for k, v in _KIND_TO_STR.items()}
_STATE_VERSION: Final = 1
GAIN_TOLERANCE: Final = 1e-9
"""How far below 0 a best gain must be for the matched allocation to leave a teleop
candidate autonomous: a gain of 0 up to rounding (no evidence either way) is not."""
_NewState = tuple[npt.NDArray[np.int64], npt.NDArray[np.int8], npt.NDArray[np.int64]]
"""Per human: the arm, kind code and served count being decided this step."""


def lex_positive(keys: npt.NDArray[np.floating[Any]]) -> npt.NDArray[np.bool_]:
    """Per row of ``keys`` (N, K): is the row lexicographically greater than zero?

    That is: its first non-zero entry is positive. An all-zero row is not.
    """
    nonzero = keys != 0
    first = np.argmax(nonzero, axis=1)
    lead = keys[np.arange(keys.shape[0]), first]
    return lead > 0


class Allocator:
    """Assign humans to arms each timestep (the paper's Algorithm 1; docs/notes/core.md).

    After :meth:`step`, per arm: :attr:`assignment` (human or -1), :attr:`kinds`
    (``InterventionKind`` or ``None``), :attr:`served` (earlier consecutive timesteps
    of the current intervention, 0 on its first), :attr:`waited` (consecutive
    timesteps the arm has waited for a human, this one included; 0: not waiting);
    :meth:`held_kinds` gives kinds and served as tuples for the fleet loop and the
    console. ``on_site`` (bool (M,); None: everyone) marks who may be given a hard
    reset (module doc).
    """

    def __init__(
        self,
        num_robots: int,
        num_humans: int,
        min_teleop_steps: int,
        hard_reset_steps: int,
        seed: int | None = None,
        on_site: npt.ArrayLike | None = None,
    ) -> None:
        for name, value, low in (
            ("num_robots", num_robots, 1),
            ("num_humans", num_humans, 0),
            ("min_teleop_steps", min_teleop_steps, 1),
            ("hard_reset_steps", hard_reset_steps, 1),
        ):
            if isinstance(value, bool) or not isinstance(value, int | np.integer):
                raise ValueError(f"{name} must be an int, got {value!r}")
            if value < low:
                raise ValueError(f"{name} must be >= {low}, got {value}")
        self.num_robots: Final[int] = int(num_robots)
        self.num_humans: Final[int] = int(num_humans)
        self.min_teleop_steps: Final[int] = int(min_teleop_steps)
        self.hard_reset_steps: Final[int] = int(hard_reset_steps)
        self.on_site: Final[npt.NDArray[np.bool_]] = (
            np.ones(self.num_humans, dtype=bool) if on_site is None
            else _bool_mask("on_site", on_site, self.num_humans).copy())
        """(M,) per human: on site (may be given a hard reset), or remote (teleops only).
        Configuration, not state: not in :meth:`state_dict`, so a resume takes the
        config's places as they are now."""
        self.on_site.setflags(write=False)
        self._rng = np.random.default_rng(seed)
        # Per human: the arm of the last step (-1: none), its kind code, its served count.
        self._human_arm = np.full(self.num_humans, -1, dtype=np.int64)
        self._human_kind = np.zeros(self.num_humans, dtype=np.int8)
        self._human_served = np.zeros(self.num_humans, dtype=np.int64)
        # Per arm: consecutive steps it has waited for a human, the last one included.
        self._arm_waited = np.zeros(self.num_robots, dtype=np.int64)
        self._steps = 0

    # ------------------------------------------------------------------ queries
    @property
    def steps(self) -> int:
        """How many times :meth:`step` has run."""
        return self._steps

    @property
    def assignment(self) -> npt.NDArray[np.int64]:
        """(N,) human index per arm after the last step, -1 for none (a copy)."""
        out = np.full(self.num_robots, -1, dtype=np.int64)
        busy = self._human_arm >= 0
        out[self._human_arm[busy]] = np.flatnonzero(busy)
        return out

    @property
    def kind_codes(self) -> npt.NDArray[np.int8]:
        """(N,) ``KIND_NONE`` / ``KIND_TELEOP`` / ``KIND_RESET`` per arm (a copy)."""
        out = np.zeros(self.num_robots, dtype=np.int8)
        busy = self._human_arm >= 0
        out[self._human_arm[busy]] = self._human_kind[busy]
        return out

    @property
    def kinds(self) -> list[InterventionKind | None]:
        """Per arm, the kind of its intervention after the last step, or ``None``."""
        return [_KIND_TO_ENUM[int(c)] for c in self.kind_codes]

    @property
    def served(self) -> npt.NDArray[np.int64]:
        """(N,) per arm, earlier consecutive steps of its intervention (0 if none)."""
        out = np.zeros(self.num_robots, dtype=np.int64)
        busy = self._human_arm >= 0
        out[self._human_arm[busy]] = self._human_served[busy]
        return out

    @property
    def waited(self) -> npt.NDArray[np.int64]:
        """(N,) per arm, consecutive steps it has waited for a human up to the last step,
        that step included (0: it did not wait at the last step; a copy). Before a step
        it is what the arms have waited so far (``PrioritySignals.waited``); after it,
        what each arm's row records (``"waited"``)."""
        return self._arm_waited.copy()

    def held_kinds(self) -> list[tuple[InterventionKind | None, int]]:
        """Per arm ``(kind, served)`` after the last step; ``(None, 0)`` for no human."""
        return [(_KIND_TO_ENUM[int(k)], int(s))
                for k, s in zip(self.kind_codes, self.served, strict=True)]

    def min_steps(self, kind: InterventionKind | str) -> int:
        """t_T for a teleop, t_R for a hard reset (``HumanRequest.min_steps``)."""
        kind = InterventionKind(kind)
        return self.min_teleop_steps if kind is InterventionKind.TELEOP else self.hard_reset_steps

    def held_mask(self, violating: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """(N,) arms whose intervention would be held at the next step, given ``violating``.

        Changes nothing; the Random baseline uses it to size its new assignments.
        """
        viol = self._check_violating(violating)
        _, _, held = self._carry_over(viol)
        mask = np.zeros(self.num_robots, dtype=bool)
        mask[self._human_arm[held]] = True
        return mask

    def held_humans(self, violating: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """(M,) humans who would be held at the next step, given ``violating``.

        Changes nothing; the human-side twin of :meth:`held_mask`, so that the Random
        baseline can count the free humans that are present (``available`` & not held).
        """
        viol = self._check_violating(violating)
        _, _, held = self._carry_over(viol)
        return held

    # ------------------------------------------------------------------- update
    def step(self, keys: npt.ArrayLike, violating: npt.ArrayLike,
             available: npt.ArrayLike | None = None,
             gains: npt.ArrayLike | None = None) -> npt.NDArray[np.int64]:
        """Allocate for one timestep; return (N,) human index per arm, -1 for none.

        ``keys`` is (N, K) (a 1-D (N,) array is read as K = 1), compared
        lexicographically, larger first; NaN is refused. ``violating`` is bool (N,).
        ``available`` is bool (M,) or ``None`` (every human available): a human who is
        not available gets no new arm and keeps no arm it is not held on, but stays on
        a held intervention (:meth:`release_human` ends that).
        ``gains`` is ``None`` (Algorithm 1: the free humans are interchangeable) or
        (M, N) float, human h's expected gain on arm i this step
        (``testbed.fleet.operators.OperatorModel.gains``): the matched allocation
        (:meth:`_pair_matched`). Held interventions, away humans and the tie draw are
        the same either way. Who may be given a violating arm is the constructor's
        ``on_site`` (module doc).
        """
        key_arr = self._check_keys(keys)
        viol = self._check_violating(violating)
        avail = self._check_available(available)
        gain_arr = None if gains is None else self._check_gains(gains)
        n, m = self.num_robots, self.num_humans
        # Drawn every step whatever the keys, so the stream (and resume) is key-independent.
        tie = self._rng.random(n)
        self._steps += 1

        prev_arm = self._human_arm
        kind, served, held = self._carry_over(viol)

        arm_held = np.zeros(n, dtype=bool)
        arm_held[prev_arm[held]] = True
        # Only the free humans who are present take arms; a free away human ends up on
        # none (new_arm -1 below) and its arm, not held, is a candidate like any other.
        free = ~held & avail
        num_free = int(np.count_nonzero(free))

        new_arm = np.where(held, prev_arm, -1)
        new_kind = np.where(held, kind, KIND_NONE).astype(np.int8)
        new_served = np.where(held, served, 0)

        if num_free and m:
            candidates = np.flatnonzero(~arm_held & lex_positive(key_arr))
            if candidates.size:
                # np.lexsort's LAST row is the primary key: key column 0, then 1, ...,
                # then the tie draw; negated for a descending order.
                sort_rows = np.vstack([tie[candidates], key_arr[candidates, ::-1].T])
                order = np.lexsort(-sort_rows)
                ranked = candidates[order]
                new = (new_arm, new_kind, new_served)
                if gain_arr is None and self.on_site.all():
                    self._pair_blind(ranked[:num_free], free, kind, served, viol, new)
                else:  # remote humans, blind: equal gains (the same pairing, rule for rule)
                    self._pair_matched(ranked, num_free, free, kind, served, viol,
                                       np.zeros((m, n)) if gain_arr is None else gain_arr,
                                       new)

        self._human_arm = new_arm.astype(np.int64)
        self._human_kind = new_kind
        self._human_served = new_served.astype(np.int64)
        self._count_waits(key_arr, viol)
        return self.assignment

    def _count_waits(self, keys: npt.NDArray[np.float64], viol: npt.NDArray[np.bool_]
                     ) -> None:
        """After the allocation: an arm with no human that violates or whose key asked
        for one waits a step more; every other arm's wait is over (0)."""
        waiting = (viol | lex_positive(keys)) & (self.assignment < 0)
        self._arm_waited = np.where(waiting, self._arm_waited + 1, 0).astype(np.int64)

    def _pair_blind(self, chosen: npt.NDArray[np.int64], free: npt.NDArray[np.bool_],
                    kind: npt.NDArray[np.int8], served: npt.NDArray[np.int64],
                    viol: npt.NDArray[np.bool_], new: _NewState) -> None:
        """Algorithm 1's pairing: the ``chosen`` arms (the top F candidates, in key
        order) go to the free humans; one whose last arm is chosen keeps it, the others
        take the rest in index order. Writes ``new`` (arm, kind, served per human)."""
        new_arm, new_kind, new_served = new
        n = self.num_robots
        prev_arm = self._human_arm
        had_arm = prev_arm >= 0
        chosen_mask = np.zeros(n, dtype=bool)
        chosen_mask[chosen] = True
        # A free human whose last arm is chosen again keeps it: no needless switch.
        keep = free & had_arm & chosen_mask[np.maximum(prev_arm, 0)]
        keep_arms = prev_arm[keep]
        kept_kind = np.where(viol[keep_arms], KIND_RESET, KIND_TELEOP).astype(np.int8)
        same = kept_kind == kind[keep]
        new_arm[keep] = keep_arms
        new_kind[keep] = kept_kind
        new_served[keep] = np.where(same, served[keep], 0)

        taken = np.zeros(n, dtype=bool)
        taken[keep_arms] = True
        rest_arms = chosen[~taken[chosen]]  # still in key order
        rest_humans = np.flatnonzero(free & ~keep)[: rest_arms.size]
        new_arm[rest_humans] = rest_arms
        new_kind[rest_humans] = np.where(viol[rest_arms], KIND_RESET, KIND_TELEOP)
        new_served[rest_humans] = 0

    def _pair_matched(self, ranked: npt.NDArray[np.int64], num_free: int,
                      free: npt.NDArray[np.bool_], kind: npt.NDArray[np.int8],
                      served: npt.NDArray[np.int64], viol: npt.NDArray[np.bool_],
                      gains: npt.NDArray[np.float64], new: _NewState) -> None:
        """The matched pairing (``algorithm.operators = "matched"``; docs/notes/core.md,
        "Allocation rules"), and the blind one when some humans are remote (with equal
        gains): the candidates in key order (``ranked``), each to the free human allowed
        on it with the highest gain on it, until no free human is left.

        * Allowed: an on-site human on any arm; a remote human on an arm that is not
          violating (a teleop) only. A candidate no free human is allowed on (a
          violating arm with only remote humans free) gets nobody; the humans stay free
          for the next candidate.
        * A teleop candidate (not violating) whose best remaining gain is below 0 (the
          policy alone is expected to do better than every free human) stays
          autonomous; the humans stay free for the next candidate. A violating arm
          always gets a person who may reset it (a reset's gain is positive anyway).
        * Ties (equal gains) go to the arm's own human of the last step, then (a teleop
          only, :meth:`_tie_winner`) to a remote human, then to a human who would not
          keep an arm among the top F (Algorithm 1's keepers), then to the lowest index.
          So humans all on site with equal gains are paired exactly as
          :meth:`_pair_blind` pairs them: the same arms, the same humans, the same kinds
          and served counts. With unequal gains, keeping one's own arm is this
          tie-break only: the top arm goes to the best person, whoever held it.
        """
        new_arm, new_kind, new_served = new
        prev_arm = self._human_arm
        own_arm = np.maximum(prev_arm, 0)
        top = np.zeros(self.num_robots, dtype=bool)
        top[ranked[:num_free]] = True
        keeper = free & (prev_arm >= 0) & top[own_arm] & (self.on_site | ~viol[own_arm])
        # Per position: the violating candidates after it (whom an on-site person serves).
        ranked_viol = viol[ranked].astype(np.int64)
        viol_after = np.cumsum(ranked_viol[::-1])[::-1] - ranked_viol
        left = free.copy()
        for p, arm in enumerate(ranked):
            if not left.any():
                break
            pool = np.flatnonzero(left & (self.on_site | ~viol[arm]))
            if pool.size == 0:
                continue  # a violating arm and only remote humans free: it waits
            g = gains[pool, arm]
            best = g.max()
            if not viol[arm] and best < -GAIN_TOLERANCE:
                continue  # the policy alone is expected to do better: autonomous
            j = self._tie_winner(pool[g == best], int(arm), bool(viol[arm]), keeper,
                                 left, int(viol_after[p]))
            k = KIND_RESET if viol[arm] else KIND_TELEOP
            new_arm[j] = arm
            new_kind[j] = k
            new_served[j] = served[j] if prev_arm[j] == arm and kind[j] == k else 0
            left[j] = False

    def _tie_winner(self, tied: npt.NDArray[np.int64], arm: int, violating: bool,
                    keeper: npt.NDArray[np.bool_], left: npt.NDArray[np.bool_],
                    viol_after: int) -> int:
        """Who of ``tied`` (free, allowed on ``arm``, equal best gain) takes ``arm``.

        The arm's own human of the last step first; except that an on-site human keeps
        a teleop arm from a tied remote one only while the on-site people left
        outnumber the violating candidates still to come (``viol_after``): a remote
        person takes the teleop rather than leave a later reset waiting. Then, for a
        teleop, remote humans before on-site ones (keep the people in the room free
        for resets); within each, a human who would not keep a top-F arm, then the
        lowest index. All on site, this is the tie rule it always was.
        """
        on_site = self.on_site
        remote = tied[~on_site[tied]]
        own = tied[self._human_arm[tied] == arm]
        if own.size:
            j = int(own[0])
            spare = int(np.count_nonzero(left & on_site)) - 1 >= viol_after
            if violating or not on_site[j] or remote.size == 0 or spare:
                return j
        for group in ((tied,) if violating else (remote, tied)):
            if group.size:
                others = group[~keeper[group]]
                return int(others[0] if others.size else group[0])
        raise AssertionError("_tie_winner: no human tied")  # the caller's pool is not empty

    def release(self, robot: int) -> int | None:
        """Free the human on arm ``robot`` now (e.g. its host faulted for good).

        Returns the human's index, or ``None`` if the arm had none. The human is free
        at the next step like any other.
        """
        if not 0 <= robot < self.num_robots:
            raise ValueError(f"robot index {robot} out of range [0, {self.num_robots})")
        hit = np.flatnonzero(self._human_arm == robot)
        if hit.size == 0:
            return None
        j = int(hit[0])
        self._free(j)
        return j

    def release_human(self, human: int) -> int | None:
        """Free human ``human`` now, whatever it holds (e.g. away past the console's
        grace period). Returns the arm it was on, or ``None`` if it had none. The arm
        is a candidate at the next step like any other; the human, once available
        again, is free like any other.
        """
        if (isinstance(human, bool) or not isinstance(human, int | np.integer)
                or not 0 <= human < self.num_humans):
            raise ValueError(f"human index {human!r} out of range [0, {self.num_humans})")
        j = int(human)
        arm = int(self._human_arm[j])
        if arm < 0:
            return None
        self._free(j)
        return arm

    def _free(self, j: int) -> None:
        self._human_arm[j] = -1
        self._human_kind[j] = KIND_NONE
        self._human_served[j] = 0

    # ------------------------------------------------------------------ resume
    def state_dict(self) -> dict[str, Any]:
        """Everything needed to continue identically, as JSON-serialisable data."""
        return {
            "version": _STATE_VERSION,
            "num_robots": self.num_robots,
            "num_humans": self.num_humans,
            "min_teleop_steps": self.min_teleop_steps,
            "hard_reset_steps": self.hard_reset_steps,
            "steps": self._steps,
            "human_arm": [int(a) for a in self._human_arm],
            "human_kind": [_KIND_TO_STR[int(k)] for k in self._human_kind],
            "human_served": [int(s) for s in self._human_served],
            "arm_waited": [int(w) for w in self._arm_waited],
            "rng": rng_state_json(self._rng),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict`'s output; the fleet shape and t_T, t_R must match.

        ``arm_waited`` may be missing (the same version 1: a checkpoint written before
        the waits were kept, whose rows have no ``"waited"`` either): every arm then
        starts its wait afresh, which changes no allocation."""
        try:
            if state["version"] != _STATE_VERSION:
                raise ValueError(f"allocator state version {state['version']!r} is not "
                                 f"{_STATE_VERSION}")
            for name in ("num_robots", "num_humans", "min_teleop_steps", "hard_reset_steps"):
                if state[name] != getattr(self, name):
                    raise ValueError(f"allocator state has {name}={state[name]!r}, this "
                                     f"allocator has {getattr(self, name)!r}")
            m = self.num_humans
            arm = np.asarray(state["human_arm"], dtype=np.int64).reshape(m)
            kind = np.asarray([_STR_TO_KIND[k] for k in state["human_kind"]],
                              dtype=np.int8).reshape(m)
            served = np.asarray(state["human_served"], dtype=np.int64).reshape(m)
            waited = np.asarray(state.get("arm_waited", [0] * self.num_robots),
                                dtype=np.int64).reshape(self.num_robots)
            steps = int(state["steps"])
            rng_state = state["rng"]
        except (KeyError, TypeError) as exc:
            raise ValueError(f"allocator state is malformed ({exc!r})") from None
        busy = arm >= 0
        if (np.any(arm >= self.num_robots) or np.any(arm < -1) or np.any(served < 0)
                or np.any((kind == KIND_NONE) == busy) or np.any(waited < 0)
                or np.unique(arm[busy]).size != int(busy.sum())):
            raise ValueError("allocator state is inconsistent (arms, kinds, served, waited)")
        try:
            self._rng = rng_from_state(rng_state)
        except ValueError as exc:
            raise ValueError(f"allocator state: {exc}") from None
        self._human_arm, self._human_kind, self._human_served = arm, kind, served
        self._arm_waited = waited
        self._steps = steps

    # ---------------------------------------------------------------- internals
    def _carry_over(
        self, viol: npt.NDArray[np.bool_]
    ) -> tuple[npt.NDArray[np.int8], npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
        """Per human: (kind, served, held) at this step, before new assignments."""
        arm = self._human_arm
        had = arm >= 0
        arm_viol = np.zeros(self.num_humans, dtype=bool)
        arm_viol[had] = viol[arm[had]]
        served = np.where(had, self._human_served + 1, 0)
        kind = self._human_kind.copy()
        convert = had & (kind == KIND_TELEOP) & arm_viol
        kind[convert] = KIND_RESET
        served[convert] = 0
        # A remote human is never held on a reset: a teleop whose arm violates ends (the
        # arm, free, is a candidate for an on-site person) instead of becoming one.
        held = had & (
            ((kind == KIND_TELEOP) & (served < self.min_teleop_steps))
            | ((kind == KIND_RESET) & ((served < self.hard_reset_steps) | arm_viol)
               & self.on_site)
        )
        return kind, served, held

    def _check_keys(self, keys: npt.ArrayLike) -> npt.NDArray[np.float64]:
        try:
            arr = np.asarray(keys, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"keys must be a float array (N, K): {exc}") from None
        if arr.ndim == 1:
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[0] != self.num_robots or arr.shape[1] < 1:
            raise ValueError(f"keys must have shape ({self.num_robots}, K) with K >= 1, "
                             f"got {np.shape(keys)}")
        if np.isnan(arr).any():
            bad = sorted({int(i) for i in np.flatnonzero(np.isnan(arr).any(axis=1))})
            raise ValueError(f"keys contain NaN for arm(s) {bad}")
        return arr

    def _check_violating(self, violating: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        return _bool_mask("violating", violating, self.num_robots)

    def _check_gains(self, gains: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The (M, N) expected gains of the matched allocation, checked."""
        try:
            arr = np.asarray(gains, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"gains must be a float array (M, N): {exc}") from None
        if arr.shape != (self.num_humans, self.num_robots):
            raise ValueError(f"gains must have shape ({self.num_humans}, {self.num_robots}) "
                             f"(humans x arms), got {np.shape(gains)}")
        if not np.isfinite(arr).all():
            raise ValueError("gains must be finite (no NaN or infinity)")
        return arr

    def _check_available(self, available: npt.ArrayLike | None) -> npt.NDArray[np.bool_]:
        """The (M,) mask of humans present this step; ``None`` means all of them."""
        if available is None:
            return np.ones(self.num_humans, dtype=bool)
        return _bool_mask("available", available, self.num_humans)


def _bool_mask(name: str, value: npt.ArrayLike, size: int) -> npt.NDArray[np.bool_]:
    """``value`` as a bool (size,) array, or a ValueError naming ``name``."""
    arr = np.asarray(value)
    if arr.dtype != np.bool_:
        raise ValueError(f"{name} must be a bool array, got dtype {arr.dtype}")
    if arr.shape != (size,):
        raise ValueError(f"{name} must have shape ({size},), got {arr.shape}")
    return arr


def rng_state_json(rng: np.random.Generator) -> dict[str, Any]:
    """A Generator's bit-generator state as plain JSON data (for ``state_dict``)."""
    state: dict[str, Any] = _jsonable(rng.bit_generator.state)
    return state


def rng_from_state(state: dict[str, Any]) -> np.random.Generator:
    """The inverse of :func:`rng_state_json`; a bad state raises ``ValueError``."""
    rng = np.random.default_rng()
    try:
        rng.bit_generator.state = state
    except (TypeError, ValueError, KeyError) as exc:
        raise ValueError(f"bad RNG state ({exc})") from None
    return rng


def _jsonable(obj: Any) -> Any:
    """numpy scalars and nested dicts -> plain JSON types (RNG states hold numpy ints)."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    return obj
