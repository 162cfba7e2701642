"""Acting: the policy's decision and the priority signals, and an act-only copy of them.

Why a copy: at the paper's fleet size (N = 100 arms) ``act`` is 0.2-0.4 s of forward
passes on this CPU, as long as a large part of the training step. The fleet loop runs
``act`` of step t beside ``train_step`` of step t, so the step costs the training step,
not the sum (docs/notes/fleet.md). Both cannot use the same networks: the optimiser
changes them in place while act reads them. ``Actor`` holds copies of the networks
``act`` reads (the policy members and the online nets of the critics; no optimiser, no
target, no data), brought up to date by ``sync()`` before the training step starts, so
the policy used at t is always the one after exactly t training steps: a twin trial
stays reproducible whatever the timing.

``infer`` is the one implementation of the maths of ``act``, shared by ``Learner.act``
(on the learner's own networks) and ``Actor.act`` (on the copies).

``learning.compile_act``: the actor's copies run through ``torch.compile`` (inductor).
Measured on this 2-core CPU (``benchmarks/bench_act.py``): act on 100 images, 5 members
+ the safety critic, 2 threads: eager 183 ms, compiled 110 ms (inductor fuses each ELU
into its convolution's output; ELU's expm1 was a third of the eager time), 11-20 s to
compile once per trial. For training, compiling lost (policy step 1008 vs 892 ms), and
at the default trial's 4 arms act is ~14 ms: so it is off by default and on in
``protocols/twin-scale.toml``. Compiled numbers differ from eager in the last bits, so a
trial is reproducible by seed with the same setting, not across settings.
"""

from __future__ import annotations

import copy
import threading
import warnings
from collections.abc import Callable, Mapping
from contextlib import AbstractContextManager
from typing import Any

import numpy as np
import numpy.typing as npt
import torch
from torch import Tensor, nn

from testbed.core.types import NUM_ACTIONS
from testbed.learning.api import PolicyOutput, check_images
from testbed.learning.critics import Combine, q_values
from testbed.learning.features import FeatureDensity
from testbed.learning.networks import TRUNK_FEATURES
from testbed.learning.policy import ensemble_signals
from testbed.learning.runtime import compiler_deterministic

CriticNets = Mapping[str, tuple[nn.Module, Combine]]
"""Critic name -> (its online twin-Q network, how its heads combine)."""


def infer(policy: nn.Module, critics: CriticNets, read: frozenset[str],
          device: torch.device, images: npt.ArrayLike,
          features: FeatureDensity | None = None) -> PolicyOutput:
    """Actions and signals for uint8 images (N, 64, 64, 3); critics not in ``read`` give
    zeros (their forward pass is skipped); ``features`` gives ``ood`` (None without);
    the trunk features (mean over members) are always given.
    The caller holds whatever lock guards the networks."""
    arr = check_images(images)
    n = arr.shape[0]
    if n == 0:
        empty = np.zeros(0, dtype=np.float32)
        return PolicyOutput(np.zeros(0, dtype=np.int64),
                            np.zeros((0, NUM_ACTIONS), dtype=np.float32),
                            empty, empty.copy(), empty.copy(), empty.copy(),
                            None if features is None else empty.copy(),
                            np.zeros((0, TRUNK_FEATURES), dtype=np.float32))
    with torch.no_grad():
        x = torch.from_numpy(arr).to(device)
        logits, feats = policy(x, features=True)
        signals = ensemble_signals(logits)
        ood = None if features is None else features.score(feats)
        actions = signals["actions"]
        zeros = torch.zeros(n, device=device)
        risk = q_values(*critics["safety"], x, actions) if "safety" in read else zeros
        goal_risk = (1.0 - q_values(*critics["goal"], x, actions) if "goal" in read
                     else zeros)

    def out(t: Tensor) -> np.ndarray:
        return t.float().cpu().numpy()

    return PolicyOutput(
        actions=actions.cpu().numpy().astype(np.int64),
        probs=out(signals["probs"]),
        uncertainty=out(signals["uncertainty"]),
        risk=out(risk),
        goal_risk=out(goal_risk.clamp(0.0, 1.0)),
        novelty=out(signals["novelty"]),
        ood=None if ood is None else out(ood),
        features=out(feats.mean(dim=0)),
    )


class Actor:
    """``act`` of a learner on copies of its networks; ``sync()`` brings them up to date.

    Made by ``Learner.acting_copy()``, which hands over what the actor reads of it: the
    lock guarding its networks, the networks themselves (``policy`` and the critics'
    online nets, copied here), how to read its current ``read_critics`` and its device.
    ``sync`` copies the weights (about 6 MB at 5 members: a millisecond or two) and the
    ``read_critics`` under that lock; call it while no training step runs (the fleet
    loop calls it just before submitting one). ``act`` takes only the actor's own lock,
    so it runs while the learner trains.
    """

    def __init__(self, lock: AbstractContextManager[Any], policy: nn.Module,
                 critics: CriticNets, read: Callable[[], frozenset[str]],
                 device: torch.device, *, compile: bool = False,
                 features: FeatureDensity | None = None) -> None:
        self._source_lock = lock
        self._source_policy = policy
        self._source_critics = dict(critics)
        self._source_read = read
        self._lock = threading.Lock()
        with lock:
            self._policy = copy.deepcopy(policy).requires_grad_(False)
            self._critics: dict[str, tuple[nn.Module, Combine]] = {
                name: (copy.deepcopy(net).requires_grad_(False), how)
                for name, (net, how) in self._source_critics.items()
            }
            self.read: frozenset[str] = read()
            self.device = device
            self._source_features = features
            self._features = None if features is None else copy.deepcopy(features)
        self.compiled = compile
        self._run_policy: nn.Module = self._policy
        self._run_critics: dict[str, tuple[nn.Module, Combine]] = self._critics
        if compile:  # compiled modules share the copies' parameters: sync() reaches them
            compiler_deterministic()
            self._run_policy = torch.compile(self._policy, dynamic=False)  # type: ignore[assignment]
            self._run_critics = {
                name: (torch.compile(net, dynamic=False), how)  # type: ignore[misc]
                for name, (net, how) in self._critics.items()}
        self._proven = not compile

    def _pairs(self) -> list[tuple[nn.Module, nn.Module]]:
        """(copy, source) for every network the actor holds."""
        sources = self._source_critics
        pairs: list[tuple[nn.Module, nn.Module]] = [
            (self._policy, self._source_policy),
            *((net, sources[name][0]) for name, (net, _) in self._critics.items())]
        if self._features is not None and self._source_features is not None:
            pairs.append((self._features, self._source_features))
        return pairs

    def sync(self) -> None:
        """Copy the learner's current weights and parts into this actor."""
        with self._source_lock, self._lock, torch.no_grad():
            for dst, src in self._pairs():
                for d, s in zip(dst.parameters(), src.parameters(), strict=True):
                    d.copy_(s)
                for d, s in zip(dst.buffers(), src.buffers(), strict=True):
                    d.copy_(s)
            self.read = self._source_read()

    def act(self, images: npt.ArrayLike) -> PolicyOutput:
        """As ``Learner.act``, on the weights of the last ``sync``."""
        images = check_images(images)  # a bad batch is the caller's error, not the compiler's
        with self._lock:
            if self._proven:
                return infer(self._run_policy, self._run_critics, self.read, self.device,
                             images, self._features)
            try:  # the first compiled call compiles; without a C compiler it fails here
                out = infer(self._run_policy, self._run_critics, self.read, self.device,
                            images, self._features)
            except Exception as exc:  # any compiler failure: act in eager mode
                first = str(exc).splitlines()[0] if str(exc) else ""
                warnings.warn(f"learning.compile_act: torch.compile failed "
                              f"({type(exc).__name__}: {first}); acting in eager mode",
                              RuntimeWarning, stacklevel=2)
                self._run_policy, self._run_critics = self._policy, self._critics
                self.compiled = False
                out = infer(self._policy, self._critics, self.read, self.device, images,
                            self._features)
            self._proven = True
            return out
