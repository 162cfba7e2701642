"""How far an image is from the policy's training data, in the policy's own feature space:
the out-of-distribution score of the failure monitor (issue 36, item 3).

Why this way: FIPER (NeurIPS 2025) alarms when an observation is out of distribution *in
the policy's own embedding* and the action is uncertain; the ensemble's uncertainty
alone misses states where every member is confidently wrong. Each member's conv trunk
gives 64 features per image; this module keeps, per member, a running mean and
covariance of the features of the minibatches the policy trains on (what it has seen,
augmented as it sees it) and scores an image by its Mahalanobis distance to them (Lee
et al., NeurIPS 2018), averaged over members and divided by sqrt(64) so that a typical
training image scores about 1.

The statistics follow the policy: every second policy update the learner passes 64 of
its labelled images, as they were added, through the updated trunks (``Learner.
_update_features``); the first ``1 / RATE`` samples are averaged exactly, later ones with
weight ``RATE``, an exponential average over about the last 4 samples (~250 images),
because the features move as the trunk trains. On the synthetic pushing task
(``tests/testbed/learning/test_policy_learning.py``, 60 updates from scratch: the
fastest-moving trunk there is), noise images against held-out scenes ranked 0.53 with a
slow average (0.02, every update), 0.97 with 0.25 every update, 0.68 with 0.25 every 4th,
0.93 with 0.4 every 2nd (kept: half the cost); scenes on a table of another colour 1.0 in
every case. They are buffers of an
``nn.Module`` kept beside the policy (not inside it: theta_0 and runs saved before them
load unchanged) and saved with the learner's training state; until the policy has trained
once the score is 0 (no reference yet), which a run's records say (``monitor.ood``).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt
import torch
from torch import Tensor, nn

from testbed.learning.networks import TRUNK_FEATURES

__all__ = ["RATE", "FeatureDensity", "PolicyFeatures"]

RATE: Final = 0.4
SHRINK: Final = 1e-3
"""Ridge on the covariance, as a share of its mean variance: a trunk's features after an
ELU are often near-collinear, and a singular covariance would make every new direction
infinitely far."""


class FeatureDensity(nn.Module):
    """Per member: the running mean (E, D) and second moment (E, D, D) of trunk features."""

    def __init__(self, members: int, dim: int) -> None:
        super().__init__()
        self.register_buffer("mean", torch.zeros(members, dim))
        self.register_buffer("second", torch.zeros(members, dim, dim))
        self.register_buffer("count", torch.zeros((), dtype=torch.int64))

    @property
    def ready(self) -> bool:
        return bool(self.count > 0)

    @torch.no_grad()
    def update(self, features: Tensor) -> None:
        """Fold in one minibatch's features (E, B, D), detached."""
        f = features.detach().float()
        self.count += 1
        rate = max(1.0 / float(self.count), RATE)
        self.mean.lerp_(f.mean(dim=1), rate)
        self.second.lerp_(torch.einsum("ebi,ebj->eij", f, f) / f.shape[1], rate)

    @torch.no_grad()
    def score(self, features: Tensor) -> Tensor:
        """Mahalanobis distance of each image (features (E, N, D)) to the training
        features, mean over members, / sqrt(D): (N,). Zeros before any update."""
        _, n, d = features.shape
        if not self.ready:
            return torch.zeros(n, device=features.device)
        mean = self.mean
        cov = self.second - torch.einsum("ei,ej->eij", mean, mean)
        ridge = SHRINK * cov.diagonal(dim1=1, dim2=2).mean(dim=1).clamp_min(1e-6)
        cov = cov + ridge[:, None, None] * torch.eye(d, device=cov.device)
        diff = features.float() - mean[:, None, :]
        solved = torch.linalg.solve(cov, diff.transpose(1, 2))  # (E, D, N)
        d2 = (diff.transpose(1, 2) * solved).sum(dim=1).clamp_min(0.0)  # (E, N)
        return d2.sqrt().mean(dim=0) / math.sqrt(d)


class PolicyFeatures:
    """The trunk features (N, 64), mean over the ensemble's members, of uint8 images
    (N, 64, 64, 3) under the policy saved in a learner checkpoint (a run's
    ``learner-start.pt`` is its theta_0): what the failure head reads
    (``testbed/monitor/failure_head.py``); live, ``act`` gives the same of the current
    policy (``PolicyOutput.features``). Only the policy's weights are loaded, once; call
    it on as many batches as the caller reads (a 100-arm run's images need not all be
    in memory at once)."""

    def __init__(self, checkpoint_path: str | Path, batch: int = 256) -> None:
        from testbed.learning import checkpoint
        from testbed.learning.learning_config import LearningConfig
        from testbed.learning.policy import PolicyEnsemble

        state = checkpoint.load_any(checkpoint_path)
        self.policy = PolicyEnsemble(LearningConfig.model_validate(state["cfg"]).ensemble_size)
        self.policy.load_state_dict(state["policy"])
        self.policy.eval()
        self.batch = batch

    def __call__(self, images: npt.ArrayLike) -> np.ndarray:
        arr = np.asarray(images, dtype=np.uint8)
        out = np.zeros((arr.shape[0], TRUNK_FEATURES), dtype=np.float32)
        with torch.no_grad():
            for i in range(0, arr.shape[0], self.batch):
                x = torch.from_numpy(np.ascontiguousarray(arr[i:i + self.batch]))
                out[i:i + self.batch] = self.policy.trunk_features(x).mean(dim=0).numpy()
        return out
