"""The act-only copy compiled (``learning.compile_act``): same decisions as the learner's
own eager ``act``, weights followed through ``sync``, and eager again when the compiler
cannot run (a real inductor failure: no C++ compiler at the configured path)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from testbed.core.types import IMAGE_SIZE
from testbed.learning import Learner
from testbed.learning.learning_config import LearningConfig

pytestmark = pytest.mark.timeout(600)


def _images(n: int = 6) -> np.ndarray:
    return np.random.default_rng(3).integers(0, 256, (n, IMAGE_SIZE, IMAGE_SIZE, 3),
                                             dtype=np.uint8)


def _close(a: object, b: object) -> None:
    np.testing.assert_array_equal(a.actions, b.actions)  # type: ignore[attr-defined]
    for name in ("probs", "uncertainty", "risk", "goal_risk", "novelty"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), atol=1e-5,
                                   err_msg=name)


@pytest.mark.slow
def test_compiled_actor_acts_as_the_learner_and_follows_sync() -> None:
    torch._dynamo.reset()
    learner = Learner(LearningConfig(ensemble_size=2, compile_act=True), seed=2)
    actor = learner.acting_copy()
    imgs = _images()
    _close(actor.act(imgs), learner.act(imgs))
    assert actor.compiled  # the compiler ran: not the eager fallback
    with torch.no_grad():
        for net in (learner.policy, learner.safety.net):
            for p in net.parameters():
                p.mul_(1.5)
    actor.sync()
    now = learner.act(imgs)
    _close(actor.act(imgs), now)


def test_actor_acts_eagerly_when_the_compiler_fails(monkeypatch: pytest.MonkeyPatch) -> None:
    from torch._inductor import config as inductor

    torch._dynamo.reset()
    monkeypatch.setattr(inductor.cpp, "cxx", ("/nonexistent/c++",))
    learner = Learner(LearningConfig(ensemble_size=2, compile_act=True), seed=2)
    actor = learner.acting_copy()
    imgs = _images()
    with pytest.warns(RuntimeWarning, match="compile_act: torch.compile failed"):
        out = actor.act(imgs)
    assert not actor.compiled
    np.testing.assert_array_equal(out.probs, learner.act(imgs).probs)  # eager: bit-equal
    with pytest.raises(ValueError, match="uint8"):  # a bad batch is still the caller's
        actor.act(imgs.astype(np.float32))
    torch._dynamo.reset()
