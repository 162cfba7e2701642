"""The policy: a bootstrap ensemble of the lab's CNN classifiers over the 4 face pushes.

Why an ensemble: Fleet-EnsembleDAgger and C.U.R. prioritise robots by the policy's
uncertainty, and the members' disagreement on a state is that uncertainty. Each member
trains on its own bootstrap of the data (data.py draws the per-member Poisson weights),
so members agree where data is dense and disagree away from it.

Two ways to run the members, same parameters, same maths (the checkpoint does not care):

* ``loop``: one member after the other. Fastest on a small CPU (few large kernels).
* ``vmap``: ``torch.func.vmap`` over the members' parameters stacked with ``torch.stack``
  (differentiable, so gradients land in each member's own parameters and one optimiser
  serves both ways). Fewer, larger kernels: the better bet on a GPU.

Signals for the priorities (all in [0, 1]):

* uncertainty = I(action; member) / log K, the ensemble's mutual information (BALD):
  H(mean p) - mean H(p_m). 0 when the members agree (however unsure they are together);
  it grows only with disagreement, which is what "far from the data" looks like to a
  bootstrap ensemble. With E members it cannot exceed log(min(E, K)) / log K.
* novelty = sum_k Var_m p_m(k) / (1 - 1/K): ThriftyDAgger's novelty is the variance of
  the ensemble's outputs; for a classifier that is the variance of its probabilities,
  scaled by its maximum so that it lies in [0, 1].
"""

from __future__ import annotations

import math
from typing import Any, Literal

import torch
from torch import Tensor, nn
from torch.func import functional_call, vmap

from testbed.core.types import NUM_ACTIONS
from testbed.learning.networks import TRUNK_FEATURES, lab_network
from testbed.learning.runtime import LearningError

Impl = Literal["loop", "vmap"]

NO_INDICATOR, NEGATIVE, POSITIVE = 0, 1, 2
"""The advantage indicator a conditioned policy sees (``learning.conditioning =
"advantage"``, RECAP's way: ``advantage.py``): none (dropped, or not valued yet), a push
no better than the policy's, a better one. Acting, it is told POSITIVE."""


class _IndicatorVectors(nn.Module):
    """Each member's learned vector per advantage indicator (NEGATIVE, POSITIVE), zeros
    at first."""

    def __init__(self, size: int) -> None:
        super().__init__()
        self.table = nn.Parameter(torch.zeros(size, 2, TRUNK_FEATURES))


class PolicyEnsemble(nn.Module):
    """``size`` independent members; ``forward`` gives per-member logits (E, B, K).

    ``conditioned``: each member also sees an advantage indicator, a learned vector per
    member and indicator added to its trunk's features before its head (the NO_INDICATOR
    row fixed at zero). The vectors start at zero, so a conditioned ensemble loaded from
    an unconditioned theta_0 acts as theta_0 did until training moves them."""

    def __init__(self, size: int, impl: Impl = "loop", conditioned: bool = False) -> None:
        super().__init__()
        if size < 1:
            raise ValueError("the ensemble needs at least one member")
        self.members = nn.ModuleList(lab_network(NUM_ACTIONS) for _ in range(size))
        self.impl: Impl = impl
        self._names = [name for name, _ in self.members[0].named_parameters()]
        self.indicator = _IndicatorVectors(size) if conditioned else None
        """A conditioned ensemble's vectors (registered after the members: its parameter
        is the last, as an older optimiser state is extended, :func:`fit_saved_policy`)."""

    @property
    def size(self) -> int:
        return len(self.members)

    @property
    def conditions(self) -> nn.Parameter | None:
        """(E, 2, 64): each member's vector for NEGATIVE and POSITIVE (None: not
        conditioned)."""
        return None if self.indicator is None else self.indicator.table

    def forward(self, images: Tensor, features: bool = False,
                indicator: Tensor | None = None) -> Tensor | tuple[Tensor, Tensor]:
        """``images``: uint8 (B, H, W, 3) seen by every member, or (E, B, H, W, 3) one
        batch per member. Returns logits (E, B, K); with ``features`` also each member's
        trunk features (E, B, 64), the policy's own embedding (``features.py``).
        ``indicator`` (a conditioned ensemble's; int64 (E, B)): each sample's advantage
        indicator; None: POSITIVE for all (acting). An unconditioned one refuses it."""
        per_member = images.dim() == 5
        if per_member and images.shape[0] != self.size:
            raise ValueError(f"expected {self.size} member batches, got {images.shape[0]}")
        if self.conditions is not None:
            return self._conditioned(images, per_member, features, indicator)
        if indicator is not None:
            raise ValueError("an indicator for a policy not conditioned on the advantage")
        if self.impl == "vmap":
            return self._forward_vmap(images, per_member, features)
        logits, feats = [], []
        for i, m in enumerate(self.members):
            x = images[i] if per_member else images
            if features:  # the member is Sequential(trunk, head): the same sums
                f = m[0](x)
                feats.append(f)
                logits.append(m[1](f))
            else:
                logits.append(m(x))
        out = torch.stack(logits)
        return (out, torch.stack(feats)) if features else out

    def _conditioned(self, images: Tensor, per_member: bool, features: bool,
                     indicator: Tensor | None) -> Tensor | tuple[Tensor, Tensor]:
        """Trunks, each member's indicator vector added, heads (one member after the
        other: the heads are small, the trunks the cost)."""
        feats = torch.stack([m[0](images[i] if per_member else images)
                             for i, m in enumerate(self.members)])
        assert self.conditions is not None
        table = nn.functional.pad(self.conditions, (0, 0, 1, 0))  # row 0: NO_INDICATOR
        if indicator is None:
            add = table[:, POSITIVE].unsqueeze(1)
        else:
            if indicator.shape != feats.shape[:2]:
                raise ValueError(f"indicator shape {tuple(indicator.shape)}, not "
                                 f"{tuple(feats.shape[:2])}")
            add = table[torch.arange(self.size, device=feats.device)[:, None], indicator]
        logits = torch.stack([m[1](feats[i] + add[i]) for i, m in enumerate(self.members)])
        return (logits, feats) if features else logits

    def trunk_features(self, images: Tensor) -> Tensor:
        """Each member's trunk features (E, B, 64) of uint8 images (B, H, W, 3): the
        policy's own embedding without its heads (``features.py``)."""
        if self.impl == "vmap":
            params = [dict(m.named_parameters()) for m in self.members]
            trunk = {name[2:]: torch.stack([p[name] for p in params])
                     for name in self._names if name.startswith("0.")}
            base = self.members[0][0]

            def one(member_params: dict[str, Tensor], x: Tensor) -> Tensor:
                return functional_call(base, member_params, (x,))

            return vmap(one, in_dims=(0, None))(trunk, images)
        return torch.stack([m[0](images) for m in self.members])

    def _forward_vmap(self, images: Tensor, per_member: bool, features: bool
                      ) -> Tensor | tuple[Tensor, Tensor]:
        params = [dict(m.named_parameters()) for m in self.members]
        stacked = {name: torch.stack([p[name] for p in params]) for name in self._names}
        base = self.members[0]

        def one(member_params: dict[str, Tensor], x: Tensor) -> Tensor:
            return functional_call(base, member_params, (x,))

        def both(member_params: dict[str, Tensor], x: Tensor) -> tuple[Tensor, Tensor]:
            trunk = {k[2:]: v for k, v in member_params.items() if k.startswith("0.")}
            head = {k[2:]: v for k, v in member_params.items() if k.startswith("1.")}
            f = functional_call(base[0], trunk, (x,))
            return functional_call(base[1], head, (f,)), f

        dims = (0, 0 if per_member else None)
        if features:
            logits, feats = vmap(both, in_dims=dims)(stacked, images)
            return logits, feats
        return vmap(one, in_dims=dims)(stacked, images)

    def loss(self, images: Tensor, actions: Tensor, indicator: Tensor | None = None
             ) -> tuple[Tensor, Tensor]:
        """Cross-entropy of each member on its own batch (``indicator``: a conditioned
        ensemble's, (E, B); None for one unconditioned).

        Returns (the sum over members, to backpropagate: each member's gradient is that of
        its own mean loss; the per-member losses (E,), detached)."""
        logits = self(images, indicator=indicator) if indicator is not None else self(images)
        e, b, k = logits.shape
        per_sample = nn.functional.cross_entropy(
            logits.reshape(e * b, k), actions.reshape(e * b), reduction="none"
        )
        per_member = per_sample.view(e, b).mean(dim=1)
        return per_member.sum(), per_member.detach()


def ensemble_signals(logits: Tensor) -> dict[str, Tensor]:
    """From member logits (E, N, K): mean probs, greedy actions, uncertainty, novelty."""
    probs = torch.softmax(logits.float(), dim=-1)
    k = probs.shape[-1]
    mean = probs.mean(dim=0)
    log_mean = mean.clamp_min(1e-12).log()
    entropy_of_mean = -(mean * log_mean).sum(-1)
    mean_entropy = -(probs * probs.clamp_min(1e-12).log()).sum(-1).mean(0)
    mutual_info = (entropy_of_mean - mean_entropy).clamp_min(0.0)
    variance = (probs - mean).pow(2).mean(dim=0).sum(-1)
    return {
        "probs": mean,
        "actions": mean.argmax(dim=-1),
        "uncertainty": (mutual_info / math.log(k)).clamp(0.0, 1.0),
        "novelty": (variance / (1.0 - 1.0 / k)).clamp(0.0, 1.0),
    }


def fit_saved_policy(policy: PolicyEnsemble, saved: dict[str, Any], optimizer: dict[str, Any],
                     where: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """A saved policy and its optimiser's state made to fit ``policy``: an unconditioned
    one (theta_0, any checkpoint from before conditioning) into a policy conditioned on
    the advantage gets zero indicator vectors (it acts as it did) and a fresh Adam state
    for them; a conditioned one cannot go into a policy that is not (its vectors would
    be dropped, and it would act otherwise)."""
    if "indicator.table" in saved and policy.conditions is None:
        raise LearningError(f"{where}: its policy is conditioned on the advantage; set "
                            "learning.conditioning = \"advantage\" to load it")
    if policy.conditions is None or "indicator.table" in saved:
        return saved, optimizer
    saved = {**saved, "indicator.table": torch.zeros_like(policy.conditions)}
    groups = [dict(g) for g in optimizer["param_groups"]]
    ids = list(groups[-1]["params"])
    groups[-1]["params"] = [*ids, max(ids) + 1]  # the vectors: the last parameter
    return saved, {**optimizer, "param_groups": groups}
