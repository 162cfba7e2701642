"""Testing by betting on a bounded mean, and the confidence sets it gives.

Why one module: the sequential test's e-process (:mod:`testbed.results.sequential`),
its confidence sequence, and the report's interval of a rate over a few runs
(:func:`testbed.results.intervals.rate_interval`) are the same construction
(Waudby-Smith and Ramdas, "Estimating means of bounded random variables by betting",
JRSS-B 2023): for outcomes ``x_k`` in ``[lo, hi]`` and a candidate mean ``m``, two
wealths bet on ``x_k - m``, one that it is positive (``lambda_k in [0, CAP / (m - lo)]``),
one negative (``[-CAP / (hi - m), 0]``), each ``prod_k (1 + lambda_k (x_k - m))``, the
bet aGRAPA's (``mu / (sigma^2 + mu^2)`` from the outcomes before k, with one prior
pseudo-observation of mean +-(hi - lo)/4 and variance ((hi - lo)/4)^2). If every
``x_k`` has conditional mean ``m`` given the outcomes before it, each wealth is a
nonnegative martingale (the bet is fixed before ``x_k`` is seen, and ``|lambda_k (x_k -
m)| <= CAP < 1``), and so is their average, the e-value ``e_t(m)``. Ville's inequality:
the chance that ``e_t(m)`` ever reaches ``1 / alpha`` is at most alpha.

The confidence set at time t (:func:`betting_set`) is every ``m`` whose e-value has not
reached ``1 / alpha`` at any time up to t: a confidence *sequence*, valid at every t at
once and so at any stopping time (the running intersection). Read at one fixed n it is a
confidence interval valid at that n, whatever n is (no normal approximation). At ``m =
0`` on ``[-1, 1]`` the wealths are exactly the sequential test's, so 0 is outside the set
exactly when that test has settled.

The set is computed on a grid of ``m`` (``GRID`` points strictly inside ``(lo, hi)``, the
middle among them exactly), reported as the grid points next outside its outermost kept
ones (the first rejected on each side, or ``lo``/``hi``): the exact set lies strictly
between them (where it is an interval), so the printed ends never cut it; a candidate
strictly between them and on the grid is kept.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

__all__ = ["CAP", "GRID", "BetSet", "Wealth", "betting_set", "wealth"]

CAP: Final = 0.9
"""The largest share of either wealth bet on one outcome (the sequential test's)."""
PRIOR_MEAN: Final = 0.5
PRIOR_VARIANCE: Final = 0.25
"""WSR's prior pseudo-observation on ``[-1, 1]``, scaled by (hi - lo) / 2 elsewhere."""
GRID: Final = 2001
"""Candidate means across ``(lo, hi)``: a step of 2/2002 (about 0.001) on ``[-1, 1]``."""

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Wealth:
    """The betting on ``x - m`` (last axis: outcomes)."""

    lam_up: FloatArray
    lam_down: FloatArray
    up: FloatArray
    down: FloatArray

    @property
    def e(self) -> FloatArray:
        """The e-value after each outcome: the two wealths' average."""
        return np.asarray((self.up + self.down) / 2, dtype=float)


def wealth(x: npt.ArrayLike, m: npt.ArrayLike, lo: float = -1.0, hi: float = 1.0,
           horizon: int | None = None, alpha: float = 0.05) -> Wealth:
    """Both wealths betting that the mean of ``x`` (shape ``(n,)`` or ``(rows, n)``,
    every value in ``[lo, hi]``) is not ``m`` (a number, or one per row, strictly inside
    ``(lo, hi)``); the bet at outcome k uses only the outcomes before k. ``horizon``:
    the bet for an interval read at that many outcomes (:func:`_plug_in`) instead of
    aGRAPA's (the sequential test's, for a sequence read at every outcome)."""
    xs = np.atleast_2d(np.asarray(x, dtype=float))
    ms = np.asarray(m, dtype=float).reshape(-1)
    own = xs  # the plug-in bet depends on the outcomes only: once per row of x
    rows = max(len(xs), len(ms))
    xs = np.broadcast_to(xs, (rows, xs.shape[1]))
    ms = np.broadcast_to(ms, (rows,))
    if np.any(ms <= lo) or np.any(ms >= hi):
        raise ValueError(f"a candidate mean must lie strictly inside ({lo}, {hi})")
    half = (hi - lo) / 2
    cap_up, cap_down = CAP / (ms - lo), CAP / (hi - ms)
    n = xs.shape[1]
    out = {k: np.empty((rows, n)) for k in ("lam_up", "lam_down", "up", "down")}
    sums = {1: np.full(rows, PRIOR_MEAN * half), -1: np.full(rows, -PRIOR_MEAN * half)}
    sq = {1: np.full(rows, PRIOR_VARIANCE * half * half),
          -1: np.full(rows, PRIOR_VARIANCE * half * half)}
    up, down = np.ones(rows), np.ones(rows)
    for k in range(n):
        y = xs[:, k] - ms
        if horizon is not None:
            size = _plug_in(own[:, :k], lo, hi, horizon, alpha)
            lams = {1: np.minimum(size, cap_up), -1: -np.minimum(size, cap_down)}
        else:
            lams = {}
            for side in (1, -1):
                mu = sums[side] / (k + 1)
                growth = mu / (sq[side] / (k + 1) + mu * mu)
                lams[side] = (np.clip(growth, 0.0, cap_up) if side == 1
                              else np.clip(growth, -cap_down, 0.0))
                sq[side] = sq[side] + (y - mu) ** 2
                sums[side] = sums[side] + y
        up = up * (1 + lams[1] * y)
        down = down * (1 + lams[-1] * y)
        for key, value in (("lam_up", lams[1]), ("lam_down", lams[-1]), ("up", up),
                           ("down", down)):
            out[key][:, k] = value
    return Wealth(**out)


def _plug_in(before: FloatArray, lo: float, hi: float, horizon: int, alpha: float
             ) -> FloatArray:
    """WSR's predictable plug-in bet for a confidence interval at ``horizon`` outcomes
    (their hedged capital, on ``[lo, hi]``): ``sqrt(2 log(2 / alpha) / (horizon
    sigma^2))``, capped by the caller at ``CAP / (m - lo)`` and ``CAP / (hi - m)``; the
    variance estimated from the outcomes ``before`` (rows x k) with a prior
    pseudo-observation of variance ((hi - lo) / 2)^2 / 4 around the middle, the running
    mean with the middle as a prior point."""
    k = before.shape[1]
    half = (hi - lo) / 2
    ss = np.full(len(before), PRIOR_VARIANCE * half * half)
    total = np.full(len(before), lo + half)
    for j in range(k):
        ss = ss + (before[:, j] - total / (j + 1)) ** 2
        total = total + before[:, j]
    return np.sqrt(2 * np.log(2 / alpha) / (horizon * ss / (k + 1)))


@dataclass(frozen=True)
class BetSet:
    """The confidence sequence of a mean after each outcome (:func:`betting_set`)."""

    low: FloatArray
    """After outcome t: the lower end (NaN: the set is empty)."""
    high: FloatArray


def betting_set(x: npt.ArrayLike, alpha: float, lo: float = -1.0, hi: float = 1.0,
                grid: int = GRID, fixed_n: bool = False) -> BetSet:
    """After each outcome of ``x`` (in ``[lo, hi]``, in the order observed): the
    candidate means whose e-value (:func:`wealth`) has stayed below ``1 / alpha`` so
    far, as ``[low, high]`` (module docstring: the grid and the widening).
    ``fixed_n``: bets sized for an interval read after the last outcome (WSR's
    predictable plug-in at ``len(x)``), still valid at every outcome before it."""
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1), not {alpha}")
    xs = np.asarray(x, dtype=float).reshape(-1)
    if np.any(xs < lo) or np.any(xs > hi) or not np.all(np.isfinite(xs)):
        raise ValueError(f"every outcome must be a number in [{lo}, {hi}]")
    ms = lo + (hi - lo) * np.arange(1, grid + 1) / (grid + 1)  # the middle exactly
    horizon = len(xs) if fixed_n else None
    e = wealth(xs, ms, lo, hi, horizon, alpha).e
    kept = np.maximum.accumulate(e, axis=1) < 1 / alpha
    low, high = np.full(len(xs), np.nan), np.full(len(xs), np.nan)
    for t in range(len(xs)):
        inside = np.flatnonzero(kept[:, t])
        if len(inside):
            low[t] = ms[inside[0] - 1] if inside[0] > 0 else lo
            high[t] = ms[inside[-1] + 1] if inside[-1] < grid - 1 else hi
    return BetSet(low, high)
