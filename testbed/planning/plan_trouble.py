"""``testbed plan``'s model of an arm: calm or in trouble, a hidden state fitted by EM.

Why a hidden state: on the twin an arm's requests and violations are not independent
draws. An arm whose key asked and got no one asks again far more often than a calm one
(0.42-0.60 against 0.19-0.30 per step over the fit's runs), the longer it has waited the
more often (0.51 after one unserved step, 0.70 after two or three, 0.84 after four to
nine at 8 arms and 2 humans), and almost every violation of a policy push comes from
such an arm (0.08-0.13 per push, against 0.003-0.008 from a calm one). How many arms wait
depends on how many people there are, so a model with one request rate carries the fit's
M to every other M: with one person it sees too few requests, resets and idle arms, with
four too many. This is neglect as the supervisory-control literature has it (Olsen and
Goodrich 2003; Crandall et al. 2005): an unattended robot's state degrades until a
person attends to it (docs/notes/plan.md has the figures and the validation).

The model, per arm and step (an input-output HMM: what the humans did is an input):

* the arm is calm or in trouble (hidden); a calm arm's key asks with the phase's rate
  (``calm_ask``, by phase bin: the policy learns as the run goes on) and its policy
  pushes succeed or violate with the phase's rates; an arm in trouble asks with
  ``trouble_ask`` and pushes with ``trouble_push``;
* after a step on its own (no human's push, not violating) a calm arm falls into
  trouble with ``to_trouble`` and a troubled one recovers alone with ``recover``;
* after a human's push it is calm with ``fixed`` (the human put the cube back where the
  policy copes), after a violating step (waiting or being reset) it starts afresh:
  troubled with ``start``, as at the run's first step.

Fitted by expectation-maximisation (Baum-Welch with the humans' actions as inputs), all
arms of all runs at once; each run's expected counts at the fit are kept, so
:meth:`PlanFit.draw` can bootstrap over runs and draw every rate from the posterior of
the reweighted counts. Two states, not more: the fit's runs identify two (the third
state a richer model would need shows up only at fleet sizes the fit never saw).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, Final

import numpy as np
import numpy.typing as npt

__all__ = ["ArmSequences", "TroubleCounts", "TroubleDraws", "arm_sequences", "draw_trouble",
           "fit_trouble"]

FloatArray = npt.NDArray[np.float64]
DRIFT, FIXED, AFRESH = 0, 1, 2
"""What happens to the hidden state after a step: it drifts (the arm was on its own),
a human's push fixed it, or it starts afresh (the arm was violating)."""
ITERATIONS: Final = 200
TOLERANCE: Final = 1e-6
"""EM stops when the log-likelihood per observed step gains less than this."""
_VIOLATING: Final = frozenset({"idle", "reset"})
_SKIP: Final = frozenset({"fault", "refused"})


@dataclass
class ArmSequences:
    """One run's arms as arrays (A arms, T steps)."""

    ask: npt.NDArray[np.int8]
    """1 the key asked, 0 it did not, -1 no key to read (violating, faulted)."""
    push: npt.NDArray[np.int8]
    """A policy push's outcome: 0 success, 1 violation, 2 neither; -1 no policy push."""
    kind: npt.NDArray[np.int8]
    """After the step: ``DRIFT``, ``FIXED`` or ``AFRESH``."""


def arm_sequences(rows: Sequence[Mapping[str, Any]]) -> ArmSequences:
    """A run's rows as each arm's sequence (arms as the first row names them)."""
    names = [str(r["robot"]) for r in rows[0]["robots"]]
    index = {n: i for i, n in enumerate(names)}
    shape = (len(names), len(rows))
    ask = np.full(shape, -1, np.int8)
    push = np.full(shape, -1, np.int8)
    kind = np.zeros(shape, np.int8)
    for t, row in enumerate(rows):
        for r in row["robots"]:
            a = index.get(str(r["robot"]))
            if a is None:
                continue
            mode = str(r["mode"])
            if mode in _VIOLATING:
                kind[a, t] = AFRESH
                continue
            if mode in _SKIP:
                continue
            key = r.get("key")
            if key:
                ask[a, t] = int(_asked(key))
            pushed = r.get("action") is not None
            if mode == "autonomous" and pushed:
                push[a, t] = 0 if r["success"] else 1 if r["violation"] else 2
            elif mode == "teleop" and pushed:
                kind[a, t] = FIXED
    return ArmSequences(ask, push, kind)


def _asked(key: Sequence[float]) -> bool:
    for v in key:
        if v != 0:
            return v > 0
    return False


@dataclass
class TroubleCounts:
    """Expected counts (one run's, or their sum or reweighting): each rate's [events,
    trials], the pushes' outcomes per state."""

    calm_ask: FloatArray
    """(B, 2)"""
    trouble_ask: FloatArray
    to_trouble: FloatArray
    recover: FloatArray
    fixed: FloatArray
    start: FloatArray
    calm_push: FloatArray
    """(B, 3)"""
    trouble_push: FloatArray
    """(3,)"""

    @classmethod
    def zeros(cls, bins: int) -> TroubleCounts:
        return cls(np.zeros((bins, 2)), *(np.zeros(2) for _ in range(5)),
                   np.zeros((bins, 3)), np.zeros(3))

    @classmethod
    def total(cls, parts: Sequence[TroubleCounts], bins: int) -> TroubleCounts:
        """The sum of ``parts`` (zeros when there are none)."""
        out = cls.zeros(bins)
        for c in parts:
            for f in fields(cls):
                setattr(out, f.name, getattr(out, f.name) + getattr(c, f.name))
        return out

    def weighted(self, others: Sequence[TroubleCounts], w: FloatArray) -> TroubleCounts:
        """``sum_k w[..., k] * others[k]`` with a leading replicate axis (w: (R, K))."""
        return TroubleCounts(**{f.name: np.einsum(
            "rk,k...->r...", w, np.stack([getattr(o, f.name) for o in others]))
            for f in fields(self)})


@dataclass
class TroubleDraws:
    """The model's rates, one draw per replicate (R)."""

    calm_ask: FloatArray
    """(R, B)"""
    trouble_ask: FloatArray
    """(R,) and the rest likewise, but the pushes"""
    to_trouble: FloatArray
    recover: FloatArray
    fixed: FloatArray
    start: FloatArray
    calm_push: FloatArray
    """(R, B, 3)"""
    trouble_push: FloatArray
    """(R, 3)"""


@dataclass
class _Params:
    calm_ask: FloatArray
    trouble_ask: float = 0.6
    to_trouble: float = 0.05
    recover: float = 0.1
    fixed: float = 0.8
    start: float = 0.1
    calm_push: FloatArray = field(default_factory=lambda: np.array([[0.15, 0.01, 0.84]]))
    """(B, 3)"""
    trouble_push: FloatArray = field(default_factory=lambda: np.array([0.1, 0.1, 0.8]))


def fit_trouble(runs: Sequence[ArmSequences], bin_steps: int, bins: int
                ) -> tuple[TroubleCounts, list[TroubleCounts], float]:
    """EM over every arm of ``runs``: the expected counts at the fit (summed, and per
    run) and the log-likelihood per observed step."""
    if not runs:
        raise ValueError("fit_trouble: no run")
    t_max = max(s.ask.shape[1] for s in runs)
    ask, push, kind, valid, run_of = _stack(runs, t_max)
    b_of = np.minimum(np.arange(t_max) // bin_steps, bins - 1)
    pooled_ask = ask[ask >= 0].mean() if (ask >= 0).any() else 0.5
    p = _Params(np.full(bins, min(max(pooled_ask, 0.02), 0.5)),
                calm_push=np.tile([0.15, 0.01, 0.84], (bins, 1)))
    observed = max(1, int((ask >= 0).sum() + (push >= 0).sum()))
    last = -np.inf
    counts = TroubleCounts.zeros(bins)
    per_arm: list[TroubleCounts] = []
    for _ in range(ITERATIONS):
        counts, per_arm, loglik = _e_step(p, ask, push, kind, valid, b_of, bins)
        p = _m_step(counts)
        if loglik / observed - last < TOLERANCE:
            break
        last = loglik / observed
    per_run = [TroubleCounts.total([c for c, r in zip(per_arm, run_of, strict=True) if r == k],
                                   bins) for k in range(len(runs))]
    return counts, per_run, last


def _stack(runs: Sequence[ArmSequences], t_max: int
           ) -> tuple[npt.NDArray[np.int8], npt.NDArray[np.int8], npt.NDArray[np.int8],
                      npt.NDArray[np.bool_], list[int]]:
    """Every run's arms in one (A, T) block, padded with nothing observed; ``valid``:
    the step has a next step in its own run (its transition counts)."""
    parts = []
    run_of: list[int] = []
    for k, s in enumerate(runs):
        a, t = s.ask.shape
        pad = ((0, 0), (0, t_max - t))
        valid = np.zeros((a, t_max), bool)
        valid[:, :t - 1] = True
        parts.append((np.pad(s.ask, pad, constant_values=-1),
                      np.pad(s.push, pad, constant_values=-1),
                      np.pad(s.kind, pad, constant_values=DRIFT), valid))
        run_of += [k] * a
    ask, push, kind, valid = (np.concatenate(x) for x in zip(*parts, strict=True))
    return ask, push, kind, valid, run_of


def _e_step(p: _Params, ask: npt.NDArray[np.int8], push: npt.NDArray[np.int8],
            kind: npt.NDArray[np.int8], valid: npt.NDArray[np.bool_],
            b_of: npt.NDArray[np.int64], bins: int
            ) -> tuple[TroubleCounts, list[TroubleCounts], float]:
    """Forward-backward with scaling over every arm at once; expected counts per arm."""
    a_n, t_n = ask.shape
    rate = np.stack([np.broadcast_to(p.calm_ask[b_of], (a_n, t_n)),
                     np.full((a_n, t_n), p.trouble_ask)], axis=-1)
    em = np.where(ask[..., None] == 1, rate, np.where(ask[..., None] == 0, 1 - rate, 1.0))
    outs = np.stack([p.calm_push[b_of][None].repeat(a_n, 0),
                     np.broadcast_to(p.trouble_push, (a_n, t_n, 3))], axis=-2)  # (A,T,2,3)
    got = np.take_along_axis(outs, np.maximum(push, 0)[..., None, None].repeat(2, -2),
                             axis=-1)[..., 0]
    em = em * np.where(push[..., None] >= 0, got, 1.0)
    mats = np.array([[[1 - p.to_trouble, p.to_trouble], [p.recover, 1 - p.recover]],
                     [[p.fixed, 1 - p.fixed], [p.fixed, 1 - p.fixed]],
                     [[1 - p.start, p.start], [1 - p.start, p.start]]])
    trans = mats[kind]  # (A, T, 2, 2): from step t to t + 1
    alpha = np.zeros((a_n, t_n, 2))
    scale = np.zeros((a_n, t_n))
    alpha[:, 0] = np.array([1 - p.start, p.start]) * em[:, 0]
    scale[:, 0] = alpha[:, 0].sum(-1)
    alpha[:, 0] /= scale[:, 0, None]
    for t in range(1, t_n):
        alpha[:, t] = np.einsum("ai,aij->aj", alpha[:, t - 1], trans[:, t - 1]) * em[:, t]
        scale[:, t] = alpha[:, t].sum(-1)
        alpha[:, t] /= scale[:, t, None]
    beta = np.ones((a_n, t_n, 2))
    for t in range(t_n - 2, -1, -1):
        beta[:, t] = np.einsum("aij,aj->ai", trans[:, t], em[:, t + 1] * beta[:, t + 1])
        beta[:, t] /= scale[:, t + 1, None]
    gamma = alpha * beta
    gamma /= gamma.sum(-1, keepdims=True)
    xi = (alpha[:, :-1, :, None] * trans[:, :-1] * (em[:, 1:] * beta[:, 1:])[:, :, None, :])
    xi /= np.maximum(xi.sum((-1, -2), keepdims=True), 1e-300)
    per_arm = [_arm_counts(gamma[a], xi[a], ask[a], push[a], kind[a], valid[a], b_of, bins)
               for a in range(a_n)]
    return TroubleCounts.total(per_arm, bins), per_arm, float(np.log(scale).sum())


def _arm_counts(gamma: FloatArray, xi: FloatArray, ask: npt.NDArray[np.int8],
                push: npt.NDArray[np.int8], kind: npt.NDArray[np.int8],
                valid: npt.NDArray[np.bool_], b_of: npt.NDArray[np.int64], bins: int
                ) -> TroubleCounts:
    c = TroubleCounts.zeros(bins)
    seen = ask >= 0
    calm, trouble = gamma[:, 0], gamma[:, 1]
    np.add.at(c.calm_ask, b_of[seen], np.stack([calm[seen] * ask[seen], calm[seen]], -1))
    c.trouble_ask += [float((trouble[seen] * ask[seen]).sum()), float(trouble[seen].sum())]
    pushed = push >= 0
    np.add.at(c.calm_push, (b_of[pushed], push[pushed]), calm[pushed])
    np.add.at(c.trouble_push, push[pushed], trouble[pushed])
    step = valid[:-1]
    drift = step & (kind[:-1] == DRIFT)
    c.to_trouble += [float(xi[drift, 0, 1].sum()), float(xi[drift, 0].sum())]
    c.recover += [float(xi[drift, 1, 0].sum()), float(xi[drift, 1].sum())]
    fixed = step & (kind[:-1] == FIXED)
    c.fixed += [float(gamma[1:][fixed, 0].sum()), float(fixed.sum())]
    afresh = step & (kind[:-1] == AFRESH)
    c.start += [float(gamma[1:][afresh, 1].sum() + gamma[0, 1]), float(afresh.sum() + 1)]
    return c


def _m_step(c: TroubleCounts) -> _Params:
    """The rates of the counts, each with a light prior (a Beta(1, 1) or, per phase, the
    pooled calm rate with 2 pseudo-steps) so an unvisited state or bin stays defined."""
    pooled = (c.calm_ask[:, 0].sum() + 1) / (c.calm_ask[:, 1].sum() + 2)
    push_pool = (c.calm_push.sum(0) + 1) / (c.calm_push.sum() + 3)
    return _Params(
        calm_ask=(c.calm_ask[:, 0] + 2 * pooled) / (c.calm_ask[:, 1] + 2),
        trouble_ask=_beta_mean(c.trouble_ask), to_trouble=_beta_mean(c.to_trouble),
        recover=_beta_mean(c.recover), fixed=_beta_mean(c.fixed), start=_beta_mean(c.start),
        calm_push=(c.calm_push + 2 * push_pool) / (c.calm_push.sum(-1, keepdims=True) + 2),
        trouble_push=(c.trouble_push + 1) / (c.trouble_push.sum() + 3))


def _beta_mean(kn: FloatArray) -> float:
    return float((kn[0] + 1) / (kn[1] + 2))


def draw_trouble(total: TroubleCounts, per_run: Sequence[TroubleCounts],
                 w: FloatArray | None, replicates: int, rng: np.random.Generator
                 ) -> TroubleDraws:
    """Every rate from the posterior of the counts (the run-reweighted counts with
    ``w`` (R, K), else the total), with the priors of the fit's M-step."""
    r = replicates
    c = (total.weighted(per_run, w) if w is not None else
         TroubleCounts(**{f.name: np.broadcast_to(getattr(total, f.name),
                                                  (r, *getattr(total, f.name).shape))
                          for f in fields(TroubleCounts)}))
    pooled = (c.calm_ask[..., 0].sum(-1) + 1) / (c.calm_ask[..., 1].sum(-1) + 2)  # (R,)
    k, n = c.calm_ask[..., 0], c.calm_ask[..., 1]
    calm_ask = rng.beta(k + 2 * pooled[:, None], n - k + 2 * (1 - pooled[:, None]))
    push_pool = (c.calm_push.sum(1) + 1) / (c.calm_push.sum((1, 2))[:, None] + 3)  # (R, 3)

    def beta(kn: FloatArray) -> FloatArray:
        return rng.beta(kn[..., 0] + 1, kn[..., 1] - kn[..., 0] + 1)

    return TroubleDraws(
        calm_ask=calm_ask, trouble_ask=beta(c.trouble_ask), to_trouble=beta(c.to_trouble),
        recover=beta(c.recover), fixed=beta(c.fixed), start=beta(c.start),
        calm_push=_dirichlet(c.calm_push + 2 * push_pool[:, None, :], rng),
        trouble_push=_dirichlet(c.trouble_push + 1, rng))


def _dirichlet(alpha: FloatArray, rng: np.random.Generator) -> FloatArray:
    g = rng.gamma(alpha)
    return g / g.sum(axis=-1, keepdims=True)
