"""The value of every push: an advantage for each (image, action), from the value critic.

Why: learning by class (``weighting = "intervention"``) keeps a robot push by its
episode's outcome; nothing said what one push was worth. The value critic (the learner's
``VALUE``) learns what the goal critic learns (``critics.py``: reward 1 at a success,
done at a success or a violation, the deployed policy acting after) at a shorter
horizon, ``gamma_value``: Q(s, a) is then about "the goal, soon" after push ``a`` from
``s``, where the goal critic's 0.999 (ThriftyDAgger's, kept for Fleet-ThriftyDAgger's
goal risk) values nearly every push that keeps the cube in alike. The policy's own push
there is worth V(s) = Q(s, pi(s)) (pi: the ensemble's greedy action, the push the robot
would make). The advantage

    A(s, a) = Q(s, a) - Q(s, pi(s))            in [-1, 1]

says how much more the push ``a`` brings the goal than the policy's own: above 0 for a
correction that helps, below 0 for a push worse than the policy's. It is RECAP's
question ("was this action better than usual here?", pi*0.6, 2025) with the critic's
value of the policy as the baseline, one definition for every sample: a demonstration,
a human's push and the robot's own (a demonstration has no next state, so a return-based
estimate would need a second definition). Both Q values come from one forward pass of
the critic (its heads give every action's Q), the greedy action from one of the policy.
How the horizon was chosen, and how well A ranks pushes against the twin's truth:
docs/notes/learning.md, "The value of every push".

Two ways to learn from it, each on every push (the demonstrations, the humans' and the
robot's own in any episode), both from the advantages kept per sample
(:class:`AdvantageState`): new samples are valued every :data:`NEW_EVERY` policy
updates, every sample again every ``advantage_refresh`` updates (a pass over the data
costs about two training steps, ``benchmarks/bench_weighting.py``):

* ``learning.weighting = "advantage"``: advantage-weighted regression (AWR, Peng et al.
  2019), the simpler baseline: each sample's minibatch weight is
  ``min(exp(A / temperature), max_weight)`` (:func:`awr_weights`).
* ``learning.conditioning = "advantage"``: RECAP's way (pi*0.6, 2025): the policy sees
  an indicator, POSITIVE where the sample's advantage is above ``advantage_threshold``,
  else NEGATIVE, dropped (NO_INDICATOR) at random with probability
  ``condition_dropout`` (``policy.py``: a learned vector per member and indicator added
  to the trunk's features); acting, it is told POSITIVE: "act as a better push would".
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from testbed.learning.critics import Combine, combine_heads
from testbed.learning.policy import NEGATIVE, NO_INDICATOR, POSITIVE, ensemble_signals

__all__ = ["AdvantageState", "PushValues", "awr_weights", "push_values"]

CHUNK = 256
"""Images per forward pass when valuing many pushes (the training batch's size)."""
NEW_EVERY = 10
"""Policy updates between two valuings of the samples added since: a pass over a few
images costs a forward of every member whatever their number (4 a step cost 4-5 % of a
batch-64 step, ``benchmarks/bench_weighting.py``); they count 1 until then."""


@dataclass(frozen=True)
class PushValues:
    """What a critic says of pushes: ``q`` = Q(s, a), ``value`` = Q(s, pi(s)) and
    ``policy_action`` = pi(s); float32 / int64 (N,)."""

    q: np.ndarray
    value: np.ndarray
    policy_action: np.ndarray

    @property
    def advantage(self) -> np.ndarray:
        """A(s, a) = Q(s, a) - V(s), float32 (N,) in [-1, 1]."""
        return (self.q - self.value).astype(np.float32)


def push_values(policy: nn.Module, critic: nn.Module, combine: Combine, images: Tensor,
                actions: Tensor, device: torch.device) -> PushValues:
    """Q(s, a), V(s) and pi(s) of uint8 ``images`` (N, 64, 64, 3) and int64 ``actions``
    (N,), in chunks of :data:`CHUNK`; ``critic`` is a critic's online twin-Q net (the
    value critic's), ``combine`` its heads' combination. No gradient; the caller holds the
    lock that guards the networks."""
    n = int(images.shape[0])
    if int(actions.shape[0]) != n:
        raise ValueError(f"{n} images, {int(actions.shape[0])} actions")
    q, value, greedy = (np.zeros(n, np.float32), np.zeros(n, np.float32),
                        np.zeros(n, np.int64))
    with torch.no_grad():
        for lo in range(0, n, CHUNK):
            x = images[lo:lo + CHUNK].to(device)
            a = actions[lo:lo + CHUNK].to(device).long()
            every = torch.sigmoid(critic(x))  # (B, 2, K): each head's Q of every action
            if bool(((a < 0) | (a >= every.shape[-1])).any()):
                raise ValueError(f"actions must lie in 0..{every.shape[-1] - 1}")
            pi = ensemble_signals(policy(x))["actions"]

            def of(act: Tensor, every: Tensor = every) -> Tensor:
                heads = every.gather(2, act.view(-1, 1, 1).expand(-1, 2, 1)).squeeze(2)
                return combine_heads(heads, combine)

            q[lo:lo + CHUNK] = of(a).float().cpu().numpy()
            value[lo:lo + CHUNK] = of(pi).float().cpu().numpy()
            greedy[lo:lo + CHUNK] = pi.cpu().numpy()
    return PushValues(q, value, greedy)


def awr_weights(advantage: Tensor, temperature: float, max_weight: float) -> Tensor:
    """Advantage-weighted regression's sample weights: ``exp(A / temperature)``, at most
    ``max_weight`` (AWR's clip: one lucky sample cannot take the whole minibatch)."""
    if not temperature > 0:
        raise ValueError(f"temperature must be > 0, got {temperature!r}")
    return torch.exp(advantage.float() / temperature).clamp(max=max_weight)


class AdvantageState:
    """Each policy sample's advantage, as of the last refresh, and what training reads of
    it: AWR's weight (:meth:`weights`) and RECAP's indicator (:meth:`indicators`).

    Refreshed over every sample when the policy update count is a multiple of
    ``refresh`` (the first update included); between refreshes the samples added since
    are valued every :data:`NEW_EVERY` updates (a few a step: :meth:`extend`). The schedule depends
    on the count alone, and the advantages are saved with the learner's training state,
    so a resumed trial draws the same minibatches. A sample not valued yet (read before
    the learner's next update) counts 1 (as in uniform weighting), indicator
    NO_INDICATOR."""

    def __init__(self, temperature: float, max_weight: float, refresh: int,
                 threshold: float = 0.0, dropout: float = 0.0) -> None:
        self.temperature = float(temperature)
        self.max_weight = float(max_weight)
        self.refresh = int(refresh)
        self.threshold = float(threshold)
        self.dropout = float(dropout)
        self.advantage = torch.zeros(0)
        """Per sample, the order added, as of the last refresh."""
        self.refreshes = 0

    def due(self, updates: int) -> bool:
        """Whether the update after ``updates`` policy updates refreshes first."""
        return updates % self.refresh == 0

    def set_advantages(self, advantage: Tensor) -> None:
        """A refresh: every sample's advantage now (order added)."""
        self.advantage = advantage.detach().float().clone()
        self.refreshes += 1

    @staticmethod
    def new_due(updates: int) -> bool:
        """Whether the update after ``updates`` values the samples added since."""
        return updates % NEW_EVERY == 0

    def extend(self, advantage: Tensor) -> None:
        """The advantages of the samples added since the last value, valued now (the
        refresh in between values them again with the nets of then)."""
        self.advantage = torch.cat([self.advantage, advantage.detach().float()])

    def weights(self, n: int) -> Tensor:
        """AWR's weights of the first ``n`` samples (:func:`awr_weights`); a sample newer
        than the last refresh counts 1."""
        w = awr_weights(self.advantage[:n], self.temperature, self.max_weight)
        return torch.cat([w, torch.ones(max(n - w.shape[0], 0))])

    def indicators(self, index: Tensor, gen: torch.Generator) -> Tensor:
        """RECAP's indicator of each drawn sample (``index``, (E, B)): POSITIVE where its
        advantage is above ``threshold``, else NEGATIVE; NO_INDICATOR for a sample not
        valued yet and, at random with probability ``dropout`` (drawn from ``gen``), for
        any, so the policy also learns to act without it."""
        have = int(self.advantage.shape[0])
        known = index < have
        adv = self.advantage[index.clamp(max=max(have - 1, 0))] if have else torch.zeros(
            index.shape)
        out = torch.where(adv > self.threshold, POSITIVE, NEGATIVE)
        out = torch.where(known, out, NO_INDICATOR)
        if self.dropout > 0:
            drop = torch.rand(index.shape, generator=gen) < self.dropout
            out = torch.where(drop, NO_INDICATOR, out)
        return out.long()

    def state_dict(self) -> dict[str, Any]:
        return {"advantage": self.advantage.clone(), "refreshes": self.refreshes}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.advantage = state["advantage"].clone().float()
        self.refreshes = int(state["refreshes"])
