"""Safety and goal critics: Q-functions of the deployed policy on a sparse 0/1 outcome.

Why: C.U.R. prioritises by risk, Q_risk(s, pi(s)), the discounted probability that the
robot's own policy soon takes the cube out of the workspace (the paper's 8.3.2, Recovery RL);
Fleet-ThriftyDAgger by goal risk, 1 - Q_goal(s, pi(s)), from the probability that it
reaches the goal (ThriftyDAgger). Both are the same machinery on different labels:

    target  y = r + gamma * (1 - done) * Qbar(s', pi(s'))
    safety: r = violation, done = violation,           gamma = gamma_safe (0.5)
    goal:   r = success,   done = success | violation, gamma = gamma_goal (0.999)

* Q is a probability, so each head outputs a logit and regresses y with binary
  cross-entropy on soft targets (a sigmoid keeps Q in [0, 1]; BCE keeps gradients alive
  for the rare positive labels where squared error on a sigmoid would flatten).
* Twin heads, pessimistic combination (TD3's clipped double-Q, turned the way that is
  conservative for each signal): the safety critic takes the MAX of its heads (assume the
  riskier estimate), the goal critic the MIN (assume the less likely success). The same
  combination is used in the target and when the critic is read (``values``).
* pi(s') is the ensemble's greedy action (the action the robot would execute), computed
  by the caller once per batch and shared by both critics: the critics estimate Q^pi of
  the deployed policy, so risk = Q_risk(s, pi(s)) is that policy's risk.
* Soft target updates, tau = 0.005 (``torch._foreach_lerp_``: one fused, deterministic op).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any, Literal

import torch
from torch import Tensor, nn

from testbed.learning.networks import TwinQNetwork

Combine = Literal["max", "min"]


@dataclass(frozen=True, slots=True)
class CriticSpec:
    """What a critic learns: its discount and which twin estimate is conservative."""

    name: str
    gamma: float
    combine: Combine
    tau: float = 0.005


@dataclass(frozen=True, slots=True)
class CriticBatch:
    """A minibatch on the device: uint8 images, int64 actions, float rewards and dones."""

    images: Tensor
    actions: Tensor
    next_images: Tensor
    next_actions: Tensor
    reward: Tensor
    done: Tensor


def combine_heads(q: Tensor, how: Combine) -> Tensor:
    """(B, 2) twin estimates -> (B,)."""
    return q.amax(dim=1) if how == "max" else q.amin(dim=1)


def q_values(net: nn.Module, combine: Combine, images: Tensor, actions: Tensor) -> Tensor:
    """Conservative Q(s, a) in [0, 1], (B,), of a twin-Q network, no gradient (the
    critic's ``values``, and the act-only copy's in ``actor.py``)."""
    with torch.no_grad():
        logits = net(images)
        taken = logits.gather(2, actions.view(-1, 1, 1).expand(-1, 2, 1)).squeeze(2)
        return combine_heads(torch.sigmoid(taken), combine)


class Critic:
    """A twin-head Q network, its Polyak-averaged target and its Adam optimiser."""

    def __init__(self, spec: CriticSpec, lr: float, device: torch.device) -> None:
        self.spec = spec
        self.net = TwinQNetwork().to(device)
        self.target = copy.deepcopy(self.net).requires_grad_(False)
        self.optimizer = torch.optim.Adam(self.net.parameters(), lr=lr)

    def values(self, images: Tensor, actions: Tensor) -> Tensor:
        """Conservative Q(s, a) in [0, 1], (B,), no gradient."""
        return q_values(self.net, self.spec.combine, images, actions)

    def update(self, batch: CriticBatch) -> float:
        """One gradient step on the TD targets of ``batch``; returns the BCE loss."""
        with torch.no_grad():
            next_logits = self.target(batch.next_images)
            idx = batch.next_actions.view(-1, 1, 1).expand(-1, 2, 1)
            next_q = combine_heads(torch.sigmoid(next_logits.gather(2, idx).squeeze(2)),
                              self.spec.combine)
            y = batch.reward + self.spec.gamma * (1.0 - batch.done) * next_q
        logits = self.net(batch.images)
        taken = logits.gather(2, batch.actions.view(-1, 1, 1).expand(-1, 2, 1)).squeeze(2)
        loss = nn.functional.binary_cross_entropy_with_logits(
            taken, y.unsqueeze(1).expand_as(taken)
        )
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        with torch.no_grad():
            torch._foreach_lerp_(
                list(self.target.parameters()), list(self.net.parameters()), self.spec.tau
            )
        return float(loss.detach())

    def set_lr(self, lr: float) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = lr

    def state_dict(self) -> dict[str, Any]:
        return {
            "net": self.net.state_dict(),
            "target": self.target.state_dict(),
            "optimizer": self.optimizer.state_dict(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.net.load_state_dict(state["net"])
        self.target.load_state_dict(state["target"])
        self.optimizer.load_state_dict(state["optimizer"])
