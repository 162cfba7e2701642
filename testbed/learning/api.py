"""What goes in and out of the learner: plain numpy dataclasses, validated once.

Why a separate module: the fleet loop, the CLI (``testbed collect`` / ``pretrain``) and
the tests build these without touching the learner's torch internals, and every array
that crosses the boundary is checked here (dtype, shape, range), so a wrong image from a
driver is a clear ``ValueError`` at the door instead of a shape error deep in a conv.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from testbed.core.types import IMAGE_SIZE, NUM_ACTIONS

EnsembleImpl = Literal["auto", "loop", "vmap"]
"""How the policy ensemble's members are evaluated: a Python loop over the members, or
``torch.func.vmap`` over their stacked parameters. ``auto`` picks the faster one for the
device (benchmarks/bench_training.py; docs/notes/learning.md)."""

ProgressFn = Callable[[str, int, int], None]
"""``progress(phase, done, total)``: phase is ``"policy"`` or ``"critics"``."""


def check_images(images: npt.ArrayLike, name: str = "images") -> np.ndarray:
    """Return ``images`` as a C-contiguous uint8 array (N, 64, 64, 3), or raise ValueError."""
    arr = np.asarray(images)
    if arr.ndim == 3:
        arr = arr[None]
    if arr.dtype != np.uint8:
        raise ValueError(f"{name}: expected uint8 images, got {arr.dtype}")
    if arr.ndim != 4 or arr.shape[1:] != (IMAGE_SIZE, IMAGE_SIZE, 3):
        raise ValueError(
            f"{name}: expected shape (N, {IMAGE_SIZE}, {IMAGE_SIZE}, 3), got {arr.shape}"
        )
    return np.ascontiguousarray(arr)


def check_actions(actions: npt.ArrayLike, n: int, name: str = "actions") -> np.ndarray:
    """Return ``actions`` as int64 (n,) in ``[0, NUM_ACTIONS)``, or raise ValueError."""
    arr = np.asarray(actions).reshape(-1)
    if arr.shape != (n,):
        raise ValueError(f"{name}: expected {n} values, got shape {np.asarray(actions).shape}")
    if n and not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{name}: expected integers, got {arr.dtype}")
    arr = arr.astype(np.int64)
    if n and (arr.min() < 0 or arr.max() >= NUM_ACTIONS):
        raise ValueError(f"{name}: values must lie in [0, {NUM_ACTIONS}), got {arr.tolist()}")
    return arr


def _check_flags(flags: npt.ArrayLike, n: int, name: str) -> np.ndarray:
    arr = np.asarray(flags).reshape(-1)
    if arr.shape != (n,):
        raise ValueError(f"{name}: expected {n} values, got shape {np.asarray(flags).shape}")
    return arr.astype(bool)


@dataclass(frozen=True, slots=True)
class PolicyOutput:
    """The policy's decision and the priority signals for N images, all numpy, all (N,).

    * ``actions``: int64, argmax of the ensemble's mean probabilities.
    * ``probs``: float32 (N, 4), the ensemble's mean probabilities.
    * ``uncertainty``: float32 in [0, 1], the ensemble's mutual information between the
      action and the member, divided by log 4 (0: members agree; 1: each member is sure
      of a different action). C.U.R.'s and Fleet-ED's ``u``.
    * ``risk``: float32 in [0, 1], Q_risk(s, pi(s)) of the safety critic: the discounted
      (gamma_safe) probability of a constraint violation, max of its twin heads.
    * ``goal_risk``: float32 in [0, 1], 1 - Q_goal(s, pi(s)) of the goal critic (min of its
      twin heads): Fleet-ThriftyDAgger's risk.
    * ``novelty``: float32 in [0, 1], the members' total variance of the action
      probabilities over its maximum (1 - 1/4): Fleet-ThriftyDAgger's novelty.
    * ``ood``: float32 >= 0, the image's Mahalanobis distance to the policy's training
      features in its own trunk's space / sqrt(64) (``features.py``; about 1 for a
      training image, 0 before the policy trained once), the failure monitor's
      out-of-distribution score; None from a learner that does not compute it.
    * ``features``: float32 (N, 64), the policy's trunk features of each image, the mean
      over its members: what the failure monitor's head reads with the signals
      (``testbed/monitor/failure_head.py``); None from a learner that does not give them.
    """

    actions: np.ndarray
    probs: np.ndarray
    uncertainty: np.ndarray
    risk: np.ndarray
    goal_risk: np.ndarray
    novelty: np.ndarray
    ood: np.ndarray | None = None
    features: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.actions.shape[0])


@dataclass(frozen=True, slots=True)
class Transitions:
    """Pushes (s, a, s', violation, success) for the critics; arrays of length N.

    ``violation``: the push took the cube out of the workspace (terminal for both critics).
    ``success``: the push reached the goal (terminal for the goal critic).
    """

    images: np.ndarray
    actions: np.ndarray
    next_images: np.ndarray
    violation: np.ndarray
    success: np.ndarray

    @classmethod
    def build(
        cls,
        images: npt.ArrayLike,
        actions: npt.ArrayLike,
        next_images: npt.ArrayLike,
        violation: npt.ArrayLike,
        success: npt.ArrayLike,
    ) -> Transitions:
        """Validate and normalise the arrays (dtype, shape, ranges)."""
        imgs = check_images(images, "images")
        n = imgs.shape[0]
        nxt = check_images(next_images, "next_images")
        if nxt.shape[0] != n:
            raise ValueError(f"next_images: expected {n} images, got {nxt.shape[0]}")
        return cls(
            images=imgs,
            actions=check_actions(actions, n),
            next_images=nxt,
            violation=_check_flags(violation, n, "violation"),
            success=_check_flags(success, n, "success"),
        )

    @classmethod
    def concat(cls, parts: list[Transitions]) -> Transitions:
        if not parts:
            raise ValueError("concat needs at least one Transitions")
        return cls(
            images=np.concatenate([p.images for p in parts]),
            actions=np.concatenate([p.actions for p in parts]),
            next_images=np.concatenate([p.next_images for p in parts]),
            violation=np.concatenate([p.violation for p in parts]),
            success=np.concatenate([p.success for p in parts]),
        )

    def __len__(self) -> int:
        return int(self.images.shape[0])
