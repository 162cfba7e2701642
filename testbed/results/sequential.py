"""A protocol that stops when the answer is settled: an anytime-valid test per pair.

Why a different test from the report's. The report's sign-flip p-value is valid for a
number of trials fixed in advance; looked at after every trial, and stopped as soon as
it is small, it rejects a true "no difference" far more often than alpha (every look is
another chance). A test that may be looked at after every trial, and stopped or
extended at will, needs an *e-process*: a nonnegative process whose expected value under
the null is at most 1 at any stopping time. Ville's inequality then bounds the chance
that it ever reaches 1/alpha by alpha, however often it is looked at and whenever the
lab stops (Shafer and Vovk, "Game-Theoretic Foundations for Probability and Finance",
2019; Ramdas, Grünwald, Vovk and Shafer, "Game-theoretic statistics and safe anytime-
valid inference", Statistical Science 2023).

The e-process here is *testing by betting* on the paired differences (Waudby-Smith and
Ramdas, "Estimating means of bounded random variables by betting", JRSS-B 2023; their
aGRAPA bet, section 5). Trial k gives the difference D_k (the algorithm's metric minus
the reference's in that trial). The null is the sign-flip test's own: given the trials
before, D_k is symmetric about 0 (its sign a fair coin), which is what "no difference"
means when the two runs of a trial are exchangeable.

* **Bounded outcomes** (a betting martingale needs them): ``X_k = clip(D_k / s_k, -1,
  1)`` with the scale ``s_k = SCALE_FRACTION * mean(|D_j|, j < k)`` from the earlier
  trials only; with no earlier trial (or only zero differences) ``s_k = 0`` and ``X_k =
  sign(D_k)``. Why it stays valid: ``s_k`` is fixed before trial k is seen, and a
  symmetric variable divided by a constant and clipped symmetrically is still
  symmetric, so ``E[X_k | trials < k] = 0`` under the null. (Under a mere "mean 0"
  null the clip would bias it; symmetry is the sign-flip test's null too.) No range of
  the metric is assumed: ROHE has no useful bound, a count's bound (arms x steps) is
  far too loose to bet on.
* **The bets**: two wealth processes, one betting the algorithm is above the reference
  (``lambda_k in [0, CAP]``), one below (``[-CAP, 0]``), each ``prod_j (1 + lambda_j
  X_j)``, with ``lambda_k = mu / (sigma^2 + mu^2)`` clipped (aGRAPA: the growth-optimal
  bet for a mean ``mu`` and variance ``sigma^2``), ``mu`` and ``sigma^2`` estimated from
  ``X_j, j < k`` with one prior pseudo-observation (mean +-1/2, variance 1/4: WSR's
  prior, pointed each way), so the first trial is already bet on. Each wealth is a
  nonnegative martingale under the null (``lambda_k`` depends on trials < k only and
  ``|lambda_k X_k| <= CAP < 1``); their average, the e-value, is one too (two-sided).
* **Settled** when the e-value reaches 1/alpha (Ville); a pair stays settled, its
  direction the side whose wealth grew.
* **Futility**: one trial multiplies either wealth by at most ``1 + CAP``, so the
  e-value after r more trials is at most ``e * (1 + CAP)^r``; a pair whose bound stays
  below 1/alpha by ``max_trials`` cannot be settled in the trials the lab allows.
* **The decision** (:func:`decide`): stop when at least ``min_trials`` are done and every
  pair is settled or cannot be, or when ``max_trials`` are done; else run one more.

CAP and SCALE_FRACTION were chosen by simulation (4000 replays of normal differences,
12 trials at most, alpha 0.05; a cap of 0.75 or 0.95 and a scale of 0.25 or 1 were
within a few points): a shift of 2 sd was settled in 96% of replays, after 6.8 trials
on average; a shift of 1 sd in 52%; a shift of 0.5 sd in 14%; under the null (Student t
with 2 degrees of freedom, random signs) 3% ever reached 1/alpha in 30 trials. The first
trial alone never settles anything (two-sided, its sign is no evidence: the two wealths
cancel), so 6 trials is the fewest, as for the fixed sign-flip test at 0.05. The
fixed-design t test of 12 trials has power 0.88 at 1 sd: looking after every trial
costs power. The bound is per pair: with m pairs,
each false at most alpha; for all at once, give alpha / m (e-values need no other
correction).

Everything here is recomputed from the differences: the decision is a function of the
finished trials, so a protocol interrupted and run again decides exactly as it would
have, and raising ``max_trials`` continues a protocol stopped at its old limit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from testbed.results.betting import CAP, BetSet, Wealth, betting_set, wealth

__all__ = ["CAP", "RECORD", "SCALE_FRACTION", "Bets", "Decision", "PairState", "anytime_p",
           "bets", "confidence_sequence", "decide", "e_values", "fewest_trials", "outcomes",
           "reachable", "record"]

SCALE_FRACTION: Final = 0.5
"""The scale a difference is divided by: this share of the mean |difference| so far."""
FORMAT: Final = "sequential/1"
RECORD: Final = "sequential.json"
"""The file in a protocol's folder with each trial's e-values (:func:`record`)."""

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Bets(Wealth):
    """The betting of one or many sequences of differences (last axis: trials): the
    wealths of :class:`testbed.results.betting.Wealth` at mean 0 (``lam_up`` in [0, CAP],
    ``lam_down`` in [-CAP, 0], ``up`` and ``down`` after each trial, ``e`` their
    average, each starting at 1), with the bounded outcomes they bet on."""

    x: FloatArray = field(default_factory=lambda: np.zeros(0))
    """The bounded outcomes X_k in [-1, 1]."""


def bets(diffs: npt.ArrayLike) -> Bets:
    """The e-process of ``diffs`` (shape ``(n,)`` or ``(replays, n)``), vectorised over
    replays: the outcome and both bets at trial k use only trials before k (the bets:
    :func:`testbed.results.betting.wealth` at mean 0 on ``[-1, 1]``)."""
    x = outcomes(diffs)
    squeeze = x.ndim == 1
    w = wealth(x, 0.0)
    out = {"x": np.atleast_2d(x), "lam_up": w.lam_up, "lam_down": w.lam_down, "up": w.up,
           "down": w.down}
    if squeeze:
        out = {k: v[0] for k, v in out.items()}
    return Bets(**out)


def outcomes(diffs: npt.ArrayLike) -> FloatArray:
    """The bounded outcomes ``X_k = clip(D_k / s_k, -1, 1)`` of ``diffs`` (shape ``(n,)``
    or ``(replays, n)``), ``s_k`` = ``SCALE_FRACTION`` x the mean |difference| of the
    trials before k (none, or all 0: ``X_k = sign(D_k)``)."""
    d = np.asarray(diffs, dtype=float)
    if not np.all(np.isfinite(d)):
        raise ValueError("a paired difference is not a finite number")
    squeeze = d.ndim == 1
    d = np.atleast_2d(d)
    reps, n = d.shape
    x = np.empty((reps, n))
    abs_sum = np.zeros(reps)
    for k in range(n):
        scale = SCALE_FRACTION * abs_sum / max(k, 1)
        safe = np.where(scale > 0, scale, 1.0)
        x[:, k] = np.clip(np.where(scale > 0, d[:, k] / safe, np.sign(d[:, k])), -1.0, 1.0)
        abs_sum = abs_sum + np.abs(d[:, k])
    return x[0] if squeeze else x


def confidence_sequence(diffs: Sequence[float], alpha: float) -> BetSet:
    """The ``1 - alpha`` confidence sequence, after each trial, of the mean of the
    clipped outcomes (:func:`outcomes`) of one pair's ``diffs``: the betting set of
    :func:`testbed.results.betting.betting_set` on ``[-1, 1]``. Valid at every trial at
    once (so whenever the protocol stopped) if every trial's outcome has one
    conditional mean given the trials before; at 0 it needs only the sign-flip null and
    its wealths are this module's, so 0 leaves it exactly when the e-value reaches
    1/alpha."""
    return betting_set(outcomes(np.asarray(diffs, dtype=float).reshape(-1)), alpha)


def e_values(diffs: npt.ArrayLike) -> FloatArray:
    """The e-value after each trial (:func:`bets`)."""
    return bets(diffs).e


def anytime_p(e: npt.ArrayLike) -> float:
    """The anytime-valid p-value after the e-values ``e`` (one pair, trial by trial):
    ``min(1, 1 / max e)``. Why the largest, not the last: by Ville's inequality the
    chance under the null that the e-process *ever* reaches 1/p is at most p, so the
    running maximum may be read at any stopping time (a fixed-n p-value may not)."""
    es = np.asarray(e, dtype=float).reshape(-1)
    if es.size == 0:
        return 1.0
    top = float(np.max(es))
    return 1.0 if top <= 1.0 else 1.0 / top


FEWEST_LIMIT: Final = 1000
"""How far :func:`fewest_trials` looks (any alpha above 1e-200 is settled within it)."""


def fewest_trials(alpha: float, limit: int = FEWEST_LIMIT) -> int | None:
    """The fewest trials that can settle a pair at ``alpha``: the smallest n for which n
    same-sign differences of one size (each outcome X_k = +-1, the most one trial can
    give) bring the e-value to 1/alpha under this module's bets; None: not within
    ``limit``. Computed from :func:`e_values`, so a change to the bets changes it."""
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1), not {alpha}")
    hit = np.flatnonzero(e_values(np.ones(limit)) >= 1 / alpha)
    return int(hit[0]) + 1 if len(hit) else None


def reachable(e: float, remaining: int) -> float:
    """The largest e-value ``remaining`` more trials could bring (futility's bound)."""
    return e * (1 + CAP) ** max(remaining, 0)


@dataclass(frozen=True)
class PairState:
    """One algorithm against the reference after the finished trials."""

    algorithm: str
    differences: tuple[float, ...]
    e_values: tuple[float, ...]
    settled_after: int | None
    """How many trials settled it (the first e-value >= 1/alpha); None: not (yet)."""
    direction: int
    """+1: above the reference on the metric, -1: below (the wealth that grew); 0:
    not settled."""
    futile: bool
    """Not settled, and cannot be within ``max_trials``."""
    best: float
    """The largest e-value still reachable by ``max_trials``."""

    @property
    def status(self) -> str:
        return ("settled" if self.settled_after is not None
                else "cannot be settled" if self.futile else "open")


@dataclass(frozen=True)
class Decision:
    """What the protocol does after its finished trials."""

    trials: int
    """Finished trials (every algorithm of each)."""
    alpha: float
    """The alpha each pair is tested at (the per-comparison alpha of the family)."""
    min_trials: int
    max_trials: int
    pairs: dict[str, PairState] = field(default_factory=dict)
    stop: bool = False
    why: str = ""
    primary: tuple[str, ...] = ()
    """The pairs the decision is taken on (the primary endpoints); the others are
    secondary: computed, not waited for."""

    @property
    def threshold(self) -> float:
        return 1 / self.alpha


def _pair(name: str, diffs: Sequence[float], alpha: float, max_trials: int) -> PairState:
    b = bets(np.asarray(diffs, dtype=float).reshape(-1))
    e = b.e
    hit = np.flatnonzero(e >= 1 / alpha)
    done = len(diffs)
    now = float(e[-1]) if done else 1.0
    best = reachable(now, max_trials - done)
    if len(hit):
        k = int(hit[0])
        return PairState(name, tuple(map(float, diffs)), tuple(map(float, e)), k + 1,
                         1 if b.up[k] >= b.down[k] else -1, False, best)
    return PairState(name, tuple(map(float, diffs)), tuple(map(float, e)), None, 0,
                     best < 1 / alpha, best)


def decide(differences: Mapping[str, Sequence[float]], *, alpha: float, min_trials: int,
           max_trials: int, primary: Sequence[str] | None = None) -> Decision:
    """The stopping decision after the finished trials (``differences``: per algorithm,
    its difference from the reference in each finished trial, in trial order; all of
    one length). ``primary``: the pairs the decision waits for (None: every pair); the
    others are secondary, their e-values computed but no reason to run on or stop."""
    lengths = {len(v) for v in differences.values()}
    if len(lengths) > 1:
        raise ValueError("every pair needs one difference per finished trial")
    done = lengths.pop() if lengths else 0
    pairs = {name: _pair(name, diffs, alpha, max_trials)
             for name, diffs in differences.items()}
    chosen = tuple(differences) if primary is None else tuple(primary)
    if not set(chosen) <= set(pairs):
        raise ValueError(f"primary {sorted(set(chosen) - set(pairs))} is not a pair here")
    base = Decision(done, alpha, min_trials, max_trials, pairs, primary=chosen)
    watched = [pairs[n] for n in chosen]
    open_ = [p.algorithm for p in watched if p.status == "open"]
    futile = [p.algorithm for p in watched if p.futile]
    unsettled = [p.algorithm for p in watched if p.settled_after is None]
    every = "every pair" if len(chosen) == len(pairs) else (
        "the primary pair" if len(chosen) == 1 else "every primary pair")
    if done < min_trials:
        return base
    if not unsettled:
        return _with(base, True, f"{every} is settled")
    if done >= max_trials:
        return _with(base, True, f"max_trials ({max_trials}) reached; not settled: "
                     + ", ".join(unsettled))
    if open_:
        return base
    return _with(base, True, f"{', '.join(futile)} cannot be settled within "
                 f"max_trials ({max_trials}); every other pair is settled"
                 if len(futile) < len(watched) else
                 f"no {'primary ' if len(chosen) < len(pairs) else ''}pair can be settled "
                 f"within max_trials ({max_trials})")


def _with(d: Decision, stop: bool, why: str) -> Decision:
    return Decision(d.trials, d.alpha, d.min_trials, d.max_trials, d.pairs, stop, why,
                    d.primary)


def record(decision: Decision, *, reference: str, metric: str, seeds: Sequence[int],
           protocol: str = "", family_alpha: float | None = None,
           family: Mapping[str, int] | None = None) -> dict[str, Any]:
    """The JSON the protocol keeps in its folder (``sequential.json``): the settings,
    each trial's e-values, and per pair its differences, e-values and status.
    ``alpha``/``threshold`` are the per-comparison test's; ``family_alpha`` the
    protocol's declared alpha, split by Bonferroni over ``comparisons`` (its primary
    pairs and ``family``'s: the other protocols sharing its reference runs, each with
    its number of primary comparisons)."""
    pairs = decision.pairs
    fam = dict(family or {})
    return {
        "protocol": protocol, "primary": list(decision.primary), "family": fam,
        "family_alpha": decision.alpha if family_alpha is None else family_alpha,
        "comparisons": len(decision.primary) + sum(fam.values()),
        "format": FORMAT,
        "method": "testing by betting (Waudby-Smith and Ramdas, JRSS-B 2023, aGRAPA) on "
                  "the paired differences, clipped at a predictable scale; settled at "
                  "e >= 1/alpha (Ville's inequality)",
        "reference": reference, "metric": metric, "alpha": decision.alpha,
        "threshold": decision.threshold, "min_trials": decision.min_trials,
        "max_trials": decision.max_trials, "trials_done": decision.trials,
        "cap": CAP, "scale_fraction": SCALE_FRACTION,
        "stop": decision.stop, "why": decision.why,
        "trials": [{"trial": k, "seed": int(seeds[k]) if k < len(seeds) else None,
                    "e_values": {n: p.e_values[k] for n, p in pairs.items()}}
                   for k in range(decision.trials)],
        "pairs": {n: {"differences": list(p.differences), "e_values": list(p.e_values),
                      "settled_after": p.settled_after, "direction": p.direction,
                      "status": p.status, "best_reachable": _finite(p.best)}
                  for n, p in pairs.items()},
    }


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None
