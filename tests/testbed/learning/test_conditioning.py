"""RECAP's way (issue 46, item 2): ``learning.conditioning = "advantage"``.

The policy sees each sample's advantage indicator while it trains and is told POSITIVE
when it acts. Real ensembles and a real learner (small: 2 members, batch 8, 2 copies):
a conditioned ensemble starts as the unconditioned one it is loaded from, learns its
indicator vectors, reads the indicator it is given, saves and resumes exactly, and an
unconditioned learner refuses its checkpoint.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from testbed.core.types import IMAGE_SIZE, NUM_ACTIONS, EpisodeOutcome, FrameClass
from testbed.learning import Learner
from testbed.learning.learning_config import LearningConfig
from testbed.learning.policy import NEGATIVE, NO_INDICATOR, POSITIVE, PolicyEnsemble
from testbed.learning.runtime import LearningError

SMALL = {"ensemble_size": 2, "batch_size": 8, "augmentation_factor": 2}
COND = LearningConfig(**SMALL, conditioning="advantage", advantage_refresh=2)


def _images(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, IMAGE_SIZE, IMAGE_SIZE, 3),
                                                dtype=np.uint8)


def _filled(learner: Learner) -> Learner:
    images = _images(30)
    actions = np.random.default_rng(1).integers(0, NUM_ACTIONS, 30)
    learner.add_human(images[:10], actions[:10])
    learner.add_robot(images[10:], actions[10:], np.full(20, FrameClass.ROBOT),
                      np.full(20, EpisodeOutcome.VIOLATION))
    learner.add_transitions(images[:20], actions[:20], images[1:21], np.zeros(20, bool),
                            np.arange(20) % 4 == 0)
    return learner


@pytest.mark.parametrize("impl", ["loop", "vmap"])
def test_a_conditioned_ensemble_starts_as_its_members_and_reads_the_indicator(
        impl: str) -> None:
    torch.manual_seed(0)
    plain = PolicyEnsemble(2, impl)  # type: ignore[arg-type]
    cond = PolicyEnsemble(2, impl, conditioned=True)  # type: ignore[arg-type]
    cond.load_state_dict({**plain.state_dict(), "indicator.table": torch.zeros(2, 2, 64)})
    x = torch.from_numpy(_images(5))
    with torch.no_grad():
        base = plain(x)
        torch.testing.assert_close(cond(x), base)  # zero vectors: the same policy
        for k in (NO_INDICATOR, NEGATIVE, POSITIVE):
            torch.testing.assert_close(cond(x, indicator=torch.full((2, 5), k)), base)
        cond.conditions[:, POSITIVE - 1] = 0.5  # type: ignore[index]
        acting = cond(x)
        torch.testing.assert_close(acting, cond(x, indicator=torch.full((2, 5), POSITIVE)))
        assert not torch.allclose(acting, base)
        torch.testing.assert_close(cond(x, indicator=torch.full((2, 5), NEGATIVE)), base)
        mixed = cond(x, indicator=torch.tensor([[POSITIVE] * 5, [NO_INDICATOR] * 5]))
        torch.testing.assert_close(mixed[0], acting[0])
        torch.testing.assert_close(mixed[1], base[1])
        logits, feats = cond(x, features=True)
        torch.testing.assert_close(logits, acting)
        torch.testing.assert_close(feats, plain(x, features=True)[1])  # trunks untouched
    with pytest.raises(ValueError, match="not conditioned"):
        plain(x, indicator=torch.zeros((2, 5), dtype=torch.int64))
    with pytest.raises(ValueError, match=r"indicator shape \(2, 4\)"):
        cond(x, indicator=torch.zeros((2, 4), dtype=torch.int64))


def test_a_conditioned_learner_loads_theta_0_acts_as_it_and_learns_its_vectors(
        tmp_path: Path) -> None:
    theta0 = _filled(Learner(LearningConfig(**SMALL), seed=5))
    theta0.pretrain(transitions=None, steps=0)
    theta0.train_step()
    path = theta0.save(tmp_path / "theta0.pt")
    learner = Learner.load(path, COND)
    assert learner.robot_frames and learner.value is not None
    images = _images(6, seed=9)
    np.testing.assert_array_equal(learner.act(images).probs, theta0.act(images).probs)
    learner.set_parts(train={"policy"})
    assert learner.train_parts == {"policy", "value"}
    for _ in range(3):
        learner.train_step()
    assert learner.policy.conditions is not None
    assert float(learner.policy.conditions.detach().abs().sum()) > 0  # the vectors learnt
    # theta_0 made 1 policy update; updates 1, 2, 3 here: update 1 values every sample
    # (none valued yet), update 2 again (refresh 2), update 3 only what is new (nothing)
    assert learner.advantages is not None and learner.advantages.refreshes == 2
    saved = learner.save(tmp_path / "cond.pt")
    again = Learner.load(saved)  # its own config: conditioned
    np.testing.assert_array_equal(again.act(images).probs, learner.act(images).probs)
    with pytest.raises(LearningError, match=r"conditioned on the advantage; set "
                                            r"learning\.conditioning"):
        Learner.load(saved, LearningConfig(**SMALL))


def test_a_resumed_conditioned_learner_trains_as_the_uninterrupted_one() -> None:
    whole = _filled(Learner(COND, seed=6))
    for _ in range(3):
        whole.train_step()
    state = whole.training_state()
    for _ in range(3):
        whole.train_step()
    resumed = _filled(Learner(COND, seed=6))
    resumed.load_training_state(state)
    for _ in range(3):
        resumed.train_step()
    a, b = whole.policy.state_dict(), resumed.policy.state_dict()
    assert a.keys() == b.keys() and "indicator.table" in a
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_conditioning_alone_draws_every_push_alike_and_awr_weighs(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Conditioning without AWR draws by the bootstrap alone over every push (the class
    table all ones, no advantage weight); AWR passes each sample's weight."""
    seen: list[tuple[object, object]] = []
    for cfg in (COND, LearningConfig(**SMALL, weighting="advantage")):
        learner = _filled(Learner(cfg, seed=7))
        real = learner.policy_data.sample

        def spy(batch: int, gen: torch.Generator, class_weights: torch.Tensor | None = None,
                sample_weights: torch.Tensor | None = None, *, with_index: bool = False,
                real=real) -> object:  # type: ignore[no-untyped-def]
            seen.append((class_weights, sample_weights))
            return real(batch, gen, class_weights, sample_weights, with_index=with_index)

        monkeypatch.setattr(learner.policy_data, "sample", spy)
        learner.train_step()
    (cond_table, cond_w), (awr_table, awr_w) = seen
    assert cond_w is None and isinstance(awr_w, torch.Tensor) and awr_w.shape == (30,)
    assert torch.equal(cond_table, torch.ones_like(cond_table) * (cond_table > 0))  # type: ignore[arg-type]
    assert float(cond_table[FrameClass.ROBOT, EpisodeOutcome.VIOLATION]) == 1.0  # type: ignore[index]
    assert torch.equal(cond_table, awr_table)  # type: ignore[arg-type]
