"""A failure head: "a violation within k steps" predicted from what the policy sees and
the monitor's signals, learned from the outcomes the frame classes already label
(issue 36, item 3).

Why a logistic model on the policy's trunk features and the signals, and not a network
on the images: the trunk's 64 features (the mean over the ensemble's members) already
say where the cube is and what the policy makes of it, the signals say what it knows
(the safety critic's risk foresees the violating push itself, the features the steps
before it), and the labelled pushes of a protocol are a few thousand with a few hundred
positives: enough for 66 weights with an L2 penalty, not for a network. On the twin the
head on features and risk ranked "a violation within 3 steps" at AUROC 0.93 against
risk's 0.86, scored leave one trial seed out on runs that all shared one theta_0, so not
on a policy it never saw (docs/notes/monitor.md says how to re-measure it per trial).
L2-penalised log loss, fitted by scipy's L-BFGS (exact gradient); inputs standardised on
the training pushes. Each signal enters with its logarithm too (the long tails of ood
and uncertainty); the features enter as they are.

Where it is fitted and used: ``testbed report`` scores it leave one theta_0 out, theta_0
identified by a hash of its policy's weights (each run's pushes by a head fitted on the
runs that started from another theta_0; leave one trial seed out, said so, when every
run shares one) and writes
the head fitted on all its runs to ``failure-head.json``; ``[monitor] head`` names that
file and ``score = "fail_head"`` makes it the monitor algorithm's alarm, on the live
policy's features (``PolicyOutput.features``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

__all__ = ["FORMAT", "INPUTS", "FailureHead", "HeadError", "design"]

FORMAT: Final = "failure-head/1"
INPUTS: Final = ("uncertainty", "risk", "novelty", "ood")
"""The signals a head may read (those every run it is fitted on has)."""
L2: Final = 1e-2


class HeadError(ValueError):
    """A failure-head file that cannot be used (missing, unreadable, another format)."""


def design(scores: Mapping[str, npt.ArrayLike], inputs: Sequence[str],
           features: npt.ArrayLike | None = None) -> np.ndarray:
    """The head's input rows, per push: each signal and log(signal + 1e-4), then the
    trunk features (N, D) when given."""
    cols = []
    for name in inputs:
        v = np.asarray(scores[name], dtype=np.float64)
        cols += [v[:, None], np.log(np.clip(v, 0.0, None) + 1e-4)[:, None]]
    if features is not None:
        cols.append(np.asarray(features, dtype=np.float64))
    return np.concatenate(cols, axis=1) if cols else np.zeros((0, 0))


@dataclass
class FailureHead:
    """A fitted logistic model: standardisation, weights, bias; what it reads (the
    signals, the number of trunk features) and the horizon k it predicts."""

    inputs: tuple[str, ...]
    mean: np.ndarray
    std: np.ndarray
    weights: np.ndarray
    bias: float
    features: int = 0
    k: int = 3
    fitted_on: dict[str, Any] = field(default_factory=dict)
    """Provenance (runs, pushes, positives), kept in the file."""

    @classmethod
    def fit(cls, x: np.ndarray, y: npt.ArrayLike, inputs: Sequence[str], *,
            features: int = 0, k: int = 3) -> FailureHead:
        """Fit on rows ``x`` (``design``) and labels ``y``; ValueError without both kinds."""
        label = np.asarray(y, dtype=np.float64)
        if label.size == 0 or label.min() == label.max():
            raise ValueError("a failure head needs pushes of both outcomes")
        if x.shape[1] != 2 * len(inputs) + features:
            raise ValueError(f"{x.shape[1]} columns for {len(inputs)} signals and "
                             f"{features} features")
        from scipy.optimize import minimize  # here: a robot host's install (which loads
        # [monitor] with the config) has no scipy; only fitting needs it

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
        return cls(tuple(inputs), mean, std, res.x[:-1], float(res.x[-1]), features, k,
                   {"pushes": int(label.size), "positives": int(label.sum())})

    def predict(self, x: np.ndarray) -> np.ndarray:
        """P(violation within k steps) per row of ``design``."""
        return 1.0 / (1.0 + np.exp(-(((x - self.mean) / self.std) @ self.weights + self.bias)))

    def score(self, signals: Mapping[str, npt.ArrayLike],
              features: npt.ArrayLike | None) -> np.ndarray:
        """P(violation within k steps) per arm from its signals and trunk features."""
        if self.features:
            f = np.asarray(features, dtype=np.float64) if features is not None else None
            if f is None or f.ndim != 2 or f.shape[1] != self.features:
                raise ValueError(f"the failure head reads {self.features} trunk features "
                                 f"per arm, got {None if f is None else f.shape}")
        return self.predict(design(signals, self.inputs, features if self.features else None))

    # ---- the file ----------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        return {"format": FORMAT, "k": self.k, "inputs": list(self.inputs),
                "features": self.features, "mean": self.mean.tolist(),
                "std": self.std.tolist(), "weights": self.weights.tolist(),
                "bias": self.bias, "fitted_on": self.fitted_on}

    def save(self, path: str | Path) -> Path:
        """Write the head as JSON (temp file, then replace)."""
        out = Path(path)
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_text(json.dumps(self.to_json(), indent=1) + "\n")
        tmp.replace(out)
        return out

    @classmethod
    def load(cls, path: str | Path) -> FailureHead:
        """The head in ``path``; HeadError saying what is wrong with it."""
        try:
            doc = json.loads(Path(path).read_text())
        except OSError as exc:
            raise HeadError(f"cannot read {path}: {exc.strerror or exc}") from None
        except ValueError as exc:
            raise HeadError(f"{path} is not JSON: {exc}") from None
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise HeadError(f"{path} is not a {FORMAT} file (testbed report writes one: "
                            "failure-head.json)")
        try:
            inputs = tuple(str(s) for s in doc["inputs"])
            unknown = set(inputs) - set(INPUTS)
            if unknown:
                raise HeadError(f"{path} reads signals the monitor has not: {sorted(unknown)}")
            head = cls(inputs, np.asarray(doc["mean"], float), np.asarray(doc["std"], float),
                       np.asarray(doc["weights"], float), float(doc["bias"]),
                       int(doc["features"]), int(doc["k"]), dict(doc.get("fitted_on", {})))
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, HeadError):
                raise
            raise HeadError(f"{path} is incomplete: {exc!r}") from None
        width = 2 * len(head.inputs) + head.features
        if not head.mean.shape == head.std.shape == head.weights.shape == (width,):
            raise HeadError(f"{path}: its weights do not match {len(head.inputs)} signals "
                            f"and {head.features} features")
        return head
