"""``testbed plan --trials``: how many trials a comparison needs, from a pilot protocol.

Why: a lab decides the number of trials before the robots' day, and the report's test
has a floor (the exact sign-flip p-value of n pairs is never below 2 / 2^n: 3 trials
can never give p < 0.05). From a pilot's finished runs (the report's loading, groups
and reference rule), for every algorithm paired by trial against the reference on one
of the report's metrics, this gives the paired differences, their mean and spread, and
the trials needed for a given power at a given two-sided alpha, two ways, both shown:

* **the report's own test** (the exact sign-flip test), by simulation: ``REPLAYS``
  replays of n pairs each, drawn (a) from a normal with the pilot's mean and sd and (b)
  with replacement from the pilot's own differences, each tested exactly as the report
  tests (all 2^n sign patterns up to ``EXACT_MAX_PAIRS`` pairs; beyond, ``PATTERNS``
  random patterns, the report's Monte Carlo estimator with fewer patterns); the power
  is the share of replays with p <= alpha, and the answer the smallest n (from the
  test's floor up) whose power reaches the target. The same draws serve every n (the
  first n columns), so the power curve is not jagged by fresh noise at each n;
* **a t-based approximation**: the paired t test's power from the noncentral t (n - 1
  degrees of freedom, noncentrality d sqrt(n), d = mean / sd), and the normal formula
  with the t correction, ((z_{1-alpha/2} + z_power) / d)^2 + z_{1-alpha/2}^2 / 2
  (Guenther 1981), which the noncentral t refines.

What it assumes: that the lab's trials differ as the pilot's did (a twin pilot says
nothing of the robots' spread), and that the pilot's sd is the truth, which 3 trials
cannot promise; a protocol with ``until`` (:mod:`testbed.results.sequential`)
needs no such guess.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from testbed.core.config import ConfigError
from testbed.records.run_dir import EVAL_PREFIX
from testbed.results.intervals import EXACT_MAX_PAIRS, paired, smallest_p
from testbed.results.report import (
    METRICS,
    _groups,
    _reference,
    find_runs,
    load_run,
    trial_label,
    unfinished,
)
from testbed.results.report_tables import Table

__all__ = ["REPLAYS", "extreme_patterns", "floor_trials", "normal_trials", "plan_trials",
           "sign_flip_power", "sign_flip_ps", "t_power", "t_trials"]

REPLAYS: Final = 1000
"""Replays per n in the sign-flip power (its standard error: at most 0.016)."""
PATTERNS: Final = 1999
"""Random sign patterns per replay beyond ``EXACT_MAX_PAIRS`` pairs."""
SEED: Final = 0
_CHUNK: Final = 1 << 22
"""Entries of the replays x patterns matrix computed at once (32 MB)."""

FloatArray = npt.NDArray[np.float64]


def _tolerance(d: FloatArray) -> FloatArray:
    """Sums within this of the observed one tie with it (the float error of a sum)."""
    return np.asarray(1e-12 * np.abs(d).sum(axis=-1), dtype=float)


def _half_patterns(n: int) -> FloatArray:
    """Every sign pattern of n pairs with the first sign +1 (the other half mirrors
    them: the same |sum|), as rows of +-1."""
    bits = (np.arange(1 << (n - 1))[:, None] >> np.arange(n - 1)) & 1
    return np.hstack([np.ones((1 << (n - 1), 1)), 1.0 - 2.0 * bits])


def extreme_patterns(diffs: Sequence[float]) -> int:
    """How many of the 2^n sign patterns give a |sum| at least the observed one: the
    exact two-sided sign-flip p-value is this over 2^n (the report's ``sign_flip_p``)."""
    d = np.asarray(diffs, dtype=float)
    n = len(d)
    if n == 0:
        return 1
    if n > 24:
        raise ValueError("more than 24 pairs: enumerating 2^n patterns is too long")
    sums = _half_patterns(n) @ d
    return 2 * int(np.count_nonzero(np.abs(sums) >= abs(d.sum()) - _tolerance(d)))


def sign_flip_ps(draws: npt.ArrayLike, seed: int = SEED) -> FloatArray:
    """The two-sided sign-flip p-value of each row of ``draws`` (replays x pairs): exact
    up to ``EXACT_MAX_PAIRS`` pairs (count / 2^n), else ``(1 + count) / (1 + PATTERNS)``
    over random patterns (seeded), as the report's Monte Carlo estimates it."""
    d = np.atleast_2d(np.asarray(draws, dtype=float))
    reps, n = d.shape
    if n == 0:
        return np.full(reps, math.nan)
    exact = n <= EXACT_MAX_PAIRS
    if exact:
        pats = _half_patterns(n)
    else:
        pats = np.random.default_rng(seed).choice([-1.0, 1.0], size=(PATTERNS, n))
    obs = np.abs(d.sum(axis=1)) - _tolerance(d)
    counts = np.empty(reps)
    step = max(1, _CHUNK // len(pats))
    for lo in range(0, reps, step):
        sums = np.abs(d[lo:lo + step] @ pats.T)
        counts[lo:lo + step] = np.count_nonzero(sums >= obs[lo:lo + step, None], axis=1)
    if exact:
        return np.asarray(2 * counts / 2.0 ** n, dtype=float)
    return np.asarray((1 + counts) / (1 + PATTERNS), dtype=float)


def floor_trials(alpha: float) -> int:
    """The fewest pairs with which the sign-flip test can reach ``alpha`` at all:
    the smallest n with 2 / 2^n <= alpha."""
    n = 1
    while smallest_p(n) > alpha:
        n += 1
    return n


def sign_flip_power(draws: FloatArray, alpha: float, power: float, max_trials: int,
                    seed: int = SEED) -> tuple[int | None, float]:
    """The smallest n (from :func:`floor_trials` to ``max_trials``) at which the share
    of ``draws[:, :n]`` whose sign-flip p is <= alpha reaches ``power``, and that share
    (None: not within ``max_trials``; the share is then at ``max_trials``)."""
    start = floor_trials(alpha)
    share = 0.0
    for n in range(start, max_trials + 1):
        ps = sign_flip_ps(draws[:, :n], seed)
        share = float(np.mean(ps <= alpha * (1 + 1e-12)))
        if share >= power:
            return n, share
    return None, share


def t_power(effect: float, n: int, alpha: float) -> float:
    """The two-sided paired t test's power with n pairs at standardised effect
    ``effect`` (mean / sd of the differences): the noncentral t."""
    from scipy import stats

    if n < 2:
        return 0.0
    df = n - 1
    crit = float(stats.t.ppf(1 - alpha / 2, df))
    nc = effect * math.sqrt(n)
    return float(stats.nct.sf(crit, df, nc) + stats.nct.cdf(-crit, df, nc))


def t_trials(effect: float, alpha: float, power: float, max_trials: int
             ) -> tuple[int | None, float]:
    """The smallest n in [2, max_trials] whose :func:`t_power` reaches ``power``, and
    that power (None: not within ``max_trials``; the power is then at ``max_trials``)."""
    got = 0.0
    for n in range(2, max_trials + 1):
        got = t_power(effect, n, alpha)
        if got >= power:
            return n, got
    return None, got


def normal_trials(effect: float, alpha: float, power: float) -> float:
    """The normal formula with the t correction (Guenther 1981), rounded up:
    ((z_{1-alpha/2} + z_power) / d)^2 + z_{1-alpha/2}^2 / 2. Infinite for d = 0."""
    from scipy import stats

    if effect == 0:
        return math.inf
    za = float(stats.norm.ppf(1 - alpha / 2))
    zb = float(stats.norm.ppf(power))
    return float(math.ceil(((za + zb) / abs(effect)) ** 2 + za * za / 2 - 1e-9))


def _draws(diffs: FloatArray, kind: str, max_trials: int, seed: int) -> FloatArray:
    """``REPLAYS`` x ``max_trials`` differences: normal with the pilot's mean and sd
    (``normal``), or the pilot's own, with replacement (``resampled``)."""
    rng = np.random.default_rng([seed, 1 if kind == "normal" else 2])
    if kind == "normal":
        sd = float(np.std(diffs, ddof=1))
        return np.asarray(float(np.mean(diffs)) + sd * rng.standard_normal(
            (REPLAYS, max_trials)), dtype=float)
    return np.asarray(diffs[rng.integers(0, len(diffs), (REPLAYS, max_trials))], dtype=float)


def _cell(got: tuple[int | None, float], max_trials: int) -> str:
    n, share = got
    if n is None:
        return f"> {max_trials} ({share:.2f} at {max_trials})"
    return f"{n} ({share:.2f})"


def _row(name: str, diffs: FloatArray, keys: Sequence[object], metric: str, alpha: float,
         power: float, max_trials: int) -> tuple[list[str], list[object]]:
    fmt = "{:+.4f}" if metric == "rohe" else "{:+.1f}"
    per = ", ".join(f"{trial_label(k)}: {fmt.format(d)}" for k, d in zip(keys, diffs,
                                                                          strict=True))
    mean = float(np.mean(diffs))
    sd = float(np.std(diffs, ddof=1))
    effect = mean / sd if sd > 0 else (math.inf if mean else math.nan)
    cells = [name, str(len(diffs)), per, fmt.format(mean), fmt.format(sd).lstrip("+"),
             "-" if math.isnan(effect) else f"{effect:+.2f}"]
    if sd == 0:
        n0 = floor_trials(alpha)
        flip = (f"{n0} (1.00)" if mean and n0 <= max_trials else f"> {max_trials} (0.00)")
        cells += [flip, flip, "- (no spread)", "- (no spread)"]
        return cells, [name, len(diffs), mean, sd, "", "", "", "", ""]
    normal = sign_flip_power(_draws(diffs, "normal", max_trials, SEED), alpha, power,
                             max_trials)
    resampled = sign_flip_power(_draws(diffs, "resampled", max_trials, SEED), alpha, power,
                                max_trials)
    t = t_trials(effect, alpha, power, max_trials)
    formula = normal_trials(effect, alpha, power)
    cells += [_cell(normal, max_trials), _cell(resampled, max_trials), _cell(t, max_trials),
              "-" if math.isinf(formula) else f"{formula:.0f}"]
    return cells, [name, len(diffs), round(mean, 6), round(sd, 6), round(effect, 6),
                   normal[0] or "", resampled[0] or "", t[0] or "",
                   "" if math.isinf(formula) else int(formula)]


def _check(metric: str, alpha: float, power: float, max_trials: int) -> None:
    if metric not in METRICS:
        raise ConfigError(f"--metric: unknown metric {metric!r}; use {', '.join(METRICS)}")
    for flag, value in (("--alpha", alpha), ("--power", power)):
        if not 0 < value < 1:
            raise ConfigError(f"{flag}: {value} is not between 0 and 1")
    if max_trials < 2:
        raise ConfigError("--max-trials: at least 2 (a paired comparison needs two trials)")


def plan_trials(dirs: list[Path], *, reference: str | None, metric: str, alpha: float,
                power: float, max_trials: int) -> str:
    """The trials each comparison against the reference needs, from the finished
    learning runs in or below ``dirs`` (a pilot protocol): Markdown."""
    _check(metric, alpha, power, max_trials)
    found = [p for p in find_runs(dirs) if unfinished(p) is None]
    runs = [r for r in map(load_run, found) if not r.algorithm.startswith(EVAL_PREFIX)]
    if not runs:
        raise ConfigError("RUN_OR_PROTOCOL_DIR: no finished learning run in the folders "
                          "given (a pilot protocol's runs)")
    groups = _groups(runs)
    ref = _reference(groups, reference)
    if ref is None or len(groups) < 2:
        raise ConfigError("--reference: nothing to compare with; name one of "
                          f"{', '.join(groups)} (default: cur, or a sweep's first point)")
    values = {g: {r.trial: float(r.summary[metric]) for r in rs} for g, rs in groups.items()}
    header = ["algorithm", "pilot pairs", f"differences (minus {ref})", "mean", "sd",
              "effect (mean / sd)", "sign-flip, normal model", "sign-flip, pilot resampled",
              "paired t (noncentral t)", "normal formula + t correction"]
    rows, csv_rows = [], [["algorithm", "pairs", "mean", "sd", "effect", "n_sign_flip_normal",
                           "n_sign_flip_resampled", "n_t", "n_formula"]]
    short = []
    for name, by_trial in values.items():
        if name == ref:
            continue
        cmp = paired(by_trial, values[ref])
        if len(cmp.diffs) < 2:
            short.append(f"{name} ({len(cmp.diffs)} pair{'s' if len(cmp.diffs) != 1 else ''})")
            continue
        cells, numbers = _row(name, np.asarray(cmp.diffs, dtype=float), cmp.keys, metric,
                              alpha, power, max_trials)
        rows.append(cells)
        csv_rows.append(numbers)
    table = Table("trials", f"Trials for power {power:g} at two-sided alpha {alpha:g} "
                  f"({metric}, against {ref})", header, rows,
                  _notes(alpha, power, max_trials, short), csv_rows)
    n0 = floor_trials(alpha)
    intro = (f"# Trials a comparison needs\n\nPilot: {', '.join(str(d) for d in dirs)}: "
             f"{len(runs)} finished learning runs of {len(groups)} algorithms; reference "
             f"{ref}; metric {metric}. The sign-flip test cannot reach p <= {alpha:g} with "
             f"fewer than {n0} pairs (its smallest p-value is 2 / 2^n: {n0 - 1} pairs "
             f"{smallest_p(n0 - 1):.4g}, {n0} pairs {smallest_p(n0):.4g}), however large "
             "the difference.\n\n")
    return intro + table.markdown()


def _notes(alpha: float, power: float, max_trials: int, short: list[str]) -> list[str]:
    notes = [
        "Each cell: the fewest trials (pairs) for the power, with the power reached in "
        f"parentheses (> {max_trials}: not within --max-trials, with the power there).",
        f"sign-flip: {REPLAYS} replays of n pairs, each tested as the report tests (exact "
        f"over all 2^n sign patterns up to {EXACT_MAX_PAIRS} pairs; beyond, {PATTERNS} "
        "random patterns, p = (1 + count) / (1 + patterns)); the power is the share with "
        f"p <= {alpha:g} (its standard error about 0.015). Normal model: the pairs drawn "
        "from a normal with the pilot's mean and sd. Pilot resampled: drawn with "
        "replacement from the pilot's own differences (no normality, but only the "
        "pilot's values: a pilot whose differences all share a sign makes every replay "
        "do so, and the answer is the test's floor: optimistic).",
        "paired t: power from the noncentral t (n - 1 degrees of freedom, noncentrality "
        "d sqrt(n), d = mean / sd with the pilot's sd, n - 1 in its denominator); the "
        "normal formula with the t correction (Guenther 1981) is ((z_{1-a/2} + z_power) "
        "/ d)^2 + z_{1-a/2}^2 / 2, rounded up. The t test needs fewer trials than the "
        "sign-flip test when the normal model holds: the sign-flip test pays for "
        "assuming nothing but symmetry, most at small n, where its p-values are coarse.",
        "The pilot's sd is an estimate: from 3 trials it is often half or twice the "
        "truth, and the trials needed go with its square. Read these as an order of "
        "magnitude, or let a protocol stop when the answer is settled (until = {...}: "
        "docs/notes/report.md).",
    ]
    if short:
        notes.append("Fewer than 2 pilot pairs (no spread to plan from): " + ", ".join(short))
    return notes
