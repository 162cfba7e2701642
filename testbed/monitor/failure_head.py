"""A failure head: "a violation within k steps" predicted from the monitor's signals,
learned from the outcomes the frame classes already label (issue 36, item 3).

Why a small logistic model on the signals and not a network on the images: the signals
already summarise what the policy knows (its ensemble's disagreement, the critic's risk,
the distance to its training data), the labelled pushes of one protocol are a few
thousand with a few hundred positives, and a logistic model on four standardised inputs
(and their logarithms, for the long tails of ood and uncertainty) cannot overfit them
the way a head on 64 trunk features would. L2-penalised log loss, fitted by scipy's
L-BFGS (exact gradient); inputs standardised on the training pushes.

It is scored honestly by the report: leave one run out (each run's pushes scored by the
head fitted on the group's other runs), so no push is scored by a model that saw it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
from scipy.optimize import minimize

__all__ = ["INPUTS", "FailureHead", "design"]

INPUTS: Final = ("uncertainty", "risk", "novelty", "ood")
"""The signals the head reads, those a run has (a run without risk: the others)."""
L2: Final = 1e-2


def design(scores: Mapping[str, npt.ArrayLike], inputs: Sequence[str]) -> np.ndarray:
    """The head's input rows: each signal and log(signal + 1e-4), per push."""
    cols = []
    for name in inputs:
        v = np.asarray(scores[name], dtype=np.float64)
        cols += [v, np.log(np.clip(v, 0.0, None) + 1e-4)]
    return np.stack(cols, axis=1) if cols else np.zeros((0, 0))


@dataclass
class FailureHead:
    """A fitted logistic model: standardisation, weights, bias."""

    inputs: tuple[str, ...]
    mean: np.ndarray
    std: np.ndarray
    weights: np.ndarray
    bias: float

    @classmethod
    def fit(cls, x: np.ndarray, y: npt.ArrayLike, inputs: Sequence[str]) -> FailureHead:
        """Fit on rows ``x`` (``design``) and labels ``y``; ValueError without both kinds."""
        label = np.asarray(y, dtype=np.float64)
        if label.size == 0 or label.min() == label.max():
            raise ValueError("a failure head needs pushes of both outcomes")
        mean, std = x.mean(axis=0), x.std(axis=0) + 1e-9
        z = (x - mean) / std

        def loss(theta: np.ndarray) -> tuple[float, np.ndarray]:
            w, b = theta[:-1], theta[-1]
            logit = z @ w + b
            p = 1.0 / (1.0 + np.exp(-logit))
            nll = np.logaddexp(0.0, logit) - label * logit
            grad = p - label
            return (float(nll.mean() + L2 * w @ w),
                    np.r_[z.T @ grad / label.size + 2 * L2 * w, grad.mean()])

        res = minimize(loss, np.zeros(z.shape[1] + 1), jac=True, method="L-BFGS-B")
        return cls(tuple(inputs), mean, std, res.x[:-1], float(res.x[-1]))

    def predict(self, x: np.ndarray) -> np.ndarray:
        """P(violation within k steps) per row."""
        return 1.0 / (1.0 + np.exp(-(((x - self.mean) / self.std) @ self.weights + self.bias)))
