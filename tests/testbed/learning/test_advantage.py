"""The value of every push (issue 46): A(s, a) = Q(s, a) - Q(s, pi(s)) of the value critic, and
advantage-weighted regression (``learning.weighting = "advantage"``).

The maths on hand-set networks first (every number known), then the real learner (small:
2 members, batch 8, 2 copies): the weights it samples by, its refresh schedule, the goal
value critic it trains for them, and a resume that draws what the uninterrupted run drew.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from pydantic import ValidationError
from torch import Tensor, nn

from testbed.core.types import IMAGE_SIZE, NUM_ACTIONS, EpisodeOutcome, FrameClass
from testbed.experiments.pretraining import pretrain_critics
from testbed.learning import Learner
from testbed.learning.advantage import AdvantageState, awr_weights, push_values
from testbed.learning.learning_config import LearningConfig
from testbed.learning.policy import NEGATIVE, NO_INDICATOR, POSITIVE

SMALL = {"ensemble_size": 2, "batch_size": 8, "augmentation_factor": 2}


class _ByFirstPixel(nn.Module):
    """A stand-in network whose output depends on each image's first red value ``r``:
    ``table[r]`` (the test's own numbers), broadcast over the batch."""

    def __init__(self, table: Tensor) -> None:
        super().__init__()
        self.table = table

    def forward(self, images: Tensor) -> Tensor:
        return self.table[images[:, 0, 0, 0].long()]


def _images(codes: list[int]) -> Tensor:
    x = torch.zeros((len(codes), IMAGE_SIZE, IMAGE_SIZE, 3), dtype=torch.uint8)
    x[:, 0, 0, 0] = torch.tensor(codes, dtype=torch.uint8)
    return x


def _logit(p: float) -> float:
    return float(np.log(p / (1 - p)))


def test_the_advantage_is_q_of_the_push_minus_q_of_the_policys_push() -> None:
    # image 0: the policy pushes face 2; the heads say Q(., 2) = 0.6 / 0.5, Q(., 0) =
    # 0.9 / 0.8; image 1: the policy pushes face 1, Q(., 1) = 0.3 / 0.4, Q(., 3) = 0.1 / 0.2
    q = torch.full((2, 2, NUM_ACTIONS), _logit(0.5))
    q[0, 0, 2], q[0, 1, 2], q[0, 0, 0], q[0, 1, 0] = map(_logit, (0.6, 0.5, 0.9, 0.8))
    q[1, 0, 1], q[1, 1, 1], q[1, 0, 3], q[1, 1, 3] = map(_logit, (0.3, 0.4, 0.1, 0.2))
    members = torch.zeros((2, 2, NUM_ACTIONS))  # policy: (E=2 members, code, K)
    members[:, 0, 2] = 5.0
    members[:, 1, 1] = 5.0

    def policy(x: Tensor) -> Tensor:
        return members[:, x[:, 0, 0, 0].long()]

    goal = _ByFirstPixel(q)
    images = _images([0, 1, 0])
    actions = torch.tensor([0, 3, 2])
    low = push_values(policy, goal, "min", images, actions, torch.device("cpu"))  # type: ignore[arg-type]
    assert low.policy_action.tolist() == [2, 1, 2]
    np.testing.assert_allclose(low.q, [0.8, 0.1, 0.5], atol=1e-6)
    np.testing.assert_allclose(low.value, [0.5, 0.3, 0.5], atol=1e-6)
    np.testing.assert_allclose(low.advantage, [0.3, -0.2, 0.0], atol=1e-6)
    high = push_values(policy, goal, "max", images, actions, torch.device("cpu"))  # type: ignore[arg-type]
    np.testing.assert_allclose(high.advantage, [0.3, -0.2, 0.0], atol=1e-6)
    np.testing.assert_allclose(high.q, [0.9, 0.2, 0.6], atol=1e-6)
    with pytest.raises(ValueError, match=r"actions must lie in 0\.\.3"):
        push_values(policy, goal, "min", images, torch.tensor([0, 4, 2]),  # type: ignore[arg-type]
                    torch.device("cpu"))
    with pytest.raises(ValueError, match="3 images, 2 actions"):
        push_values(policy, goal, "min", images, actions[:2], torch.device("cpu"))  # type: ignore[arg-type]


def test_awr_weights_grow_with_the_advantage_and_stop_at_the_clip() -> None:
    a = torch.tensor([-1.0, -0.1, 0.0, 0.1, 0.2, 1.0])
    w = awr_weights(a, 0.1, 5.0)
    np.testing.assert_allclose(w.numpy(), [np.exp(-10), np.exp(-1), 1.0, np.e, 5.0, 5.0],
                               rtol=1e-6)
    with pytest.raises(ValueError, match="temperature must be > 0"):
        awr_weights(a, 0.0, 5.0)


def test_the_advantages_refresh_on_their_count_and_new_samples_count_one() -> None:
    adv = AdvantageState(0.5, 10.0, refresh=3)
    assert [adv.due(u) for u in range(7)] == [True, False, False, True, False, False, True]
    assert adv.weights(2).tolist() == [1.0, 1.0]  # never refreshed: all count 1
    adv.set_advantages(torch.tensor([0.5, -0.5]))
    w = adv.weights(4)
    np.testing.assert_allclose(w.numpy(), [np.e, 1 / np.e, 1.0, 1.0], rtol=1e-6)
    state = adv.state_dict()
    other = AdvantageState(0.5, 10.0, 3)
    other.load_state_dict(state)
    assert torch.equal(other.weights(3), adv.weights(3)) and other.refreshes == 1


def test_the_indicator_is_positive_above_the_threshold_and_dropped_at_its_rate() -> None:
    adv = AdvantageState(0.1, 20.0, 5, threshold=0.05)
    adv.set_advantages(torch.tensor([0.2, 0.05, -0.3, 0.06]))
    gen = torch.Generator().manual_seed(0)
    index = torch.tensor([[0, 1, 2, 3, 4, 9]])  # 4 and 9: added after the refresh
    got = adv.indicators(index, gen)
    assert got.tolist() == [[POSITIVE, NEGATIVE, NEGATIVE, POSITIVE, NO_INDICATOR,
                             NO_INDICATOR]] and got.dtype == torch.int64
    drop = AdvantageState(0.1, 20.0, 5, dropout=0.3)
    drop.set_advantages(torch.ones(10))
    many = drop.indicators(torch.zeros((50, 200), dtype=torch.int64), gen)
    share = float((many == NO_INDICATOR).float().mean())
    assert 0.28 < share < 0.32 and set(many.unique().tolist()) == {NO_INDICATOR, POSITIVE}
    never = AdvantageState(0.1, 20.0, 5)  # no refresh yet: nothing is known
    assert never.indicators(index, gen).eq(NO_INDICATOR).all()


def test_the_config_refuses_an_unknown_weighting_or_a_value_out_of_range() -> None:
    for bad in ({"weighting": "advantages"}, {"advantage_temperature": 0.0},
                {"advantage_temperature": 11.0}, {"advantage_max_weight": 0.5},
                {"advantage_refresh": 0}, {"advantage_temperature": float("nan")}):
        with pytest.raises(ValidationError):
            LearningConfig(**bad)  # type: ignore[arg-type]
    assert LearningConfig(weighting="advantage").advantage_temperature == 0.1


def test_theta_0_pretrains_the_value_critic_where_a_way_learns_by_advantage() -> None:
    assert pretrain_critics(["cur"]) == ["safety"]
    assert pretrain_critics(["cur"], ["uniform", "intervention"]) == ["safety"]
    assert pretrain_critics(["cur", "bc"], ["uniform", "advantage"]) == ["safety", "value"]
    assert pretrain_critics(["fleet-ed"], ["advantage"]) == ["value"]


def _data(learner: Learner, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    images = rng.integers(0, 256, (40, IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
    actions = rng.integers(0, NUM_ACTIONS, 40)
    learner.add_human(images[:20], actions[:20])
    learner.add_robot(images[20:], actions[20:], np.full(20, FrameClass.ROBOT),
                      np.full(20, EpisodeOutcome.VIOLATION))
    learner.add_transitions(images[:30], actions[:30], images[1:31], np.zeros(30, bool),
                            rng.random(30) < 0.3)
    return images, actions


def test_every_push_counts_and_the_value_critic_trains_for_the_advantage() -> None:
    cfg = LearningConfig(**SMALL, weighting="advantage", advantage_refresh=2, value_every=2)
    learner = Learner(cfg, seed=1, train={"policy", "safety"}, read={"safety"})
    assert learner.train_parts == {"policy", "safety", "value"}  # the advantage's critic
    assert learner.robot_frames
    images, actions = _data(learner)
    assert len(learner.policy_data) == 40  # a failed episode's robot pushes too
    for _ in range(5):
        learner.train_step()
    # every 2nd critic minibatch (value_every 2): 0, 2, 4; no goal critic
    assert learner.value_updates == 3 and learner.goal_updates == 0
    assert learner.advantages is not None
    assert learner.advantages.refreshes == 3  # before updates 0, 2 and 4
    learner.advantages.refresh = 1000  # from here only new samples are valued
    learner.add_human(images[:3], actions[:3])  # new labels: valued at update 10
    for _ in range(5):  # updates 5..9: not yet (NEW_EVERY 10), they count 1
        learner.train_step()
        assert learner.advantages.advantage.shape == (40,)
    assert learner.advantages.weights(43)[40:].tolist() == [1.0, 1.0, 1.0]
    learner.train_step()  # update 10: the 3 new ones valued, no refresh
    assert learner.advantages.advantage.shape == (43,) and learner.advantages.refreshes == 3
    np.testing.assert_allclose(learner.advantages.advantage[40:].numpy(),
                               learner.push_values(images[:3], actions[:3]).advantage,
                               atol=0.05)  # valued before this update's small change
    theta0 = Learner(LearningConfig(**SMALL), seed=1)
    _data(theta0)
    theta0.pretrain(transitions=None, steps=0)
    from testbed.learning import Transitions

    theta0.pretrain(transitions=Transitions.build(images[:8], actions[:8], images[1:9],
                                                  np.zeros(8, bool), np.ones(8, bool)),
                    steps=4, critics=["value"])
    assert theta0.value_updates == 4  # pretraining: every minibatch
    want = learner.push_values(images, actions).advantage
    bc = Learner(LearningConfig(**SMALL, weighting="advantage"), seed=1, train=(), read=())
    assert bc.train_parts == frozenset()  # nothing trains: no critic either
    plain = Learner(LearningConfig(**SMALL), seed=1)
    assert plain.value is None and plain.train_parts == {"policy", "safety", "goal"}
    assert want.shape == (40,) and np.all(np.abs(want) <= 1.0)


def test_a_high_advantage_sample_is_drawn_more_often() -> None:
    cfg = LearningConfig(**SMALL, weighting="advantage", advantage_temperature=0.1)
    learner = Learner(cfg, seed=2)
    rng = np.random.default_rng(2)
    images = rng.integers(0, 256, (40, IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
    learner.add_human(images, np.where(np.arange(40) < 4, 0, 1 + np.arange(40) % 3))
    adv = learner.advantages
    assert adv is not None
    adv.set_advantages(torch.where(torch.arange(40) < 4, 0.3, -0.3))  # 4 good, 36 bad
    gen = torch.Generator().manual_seed(0)
    drawn = torch.cat([learner.policy_data.sample(8, gen, None, adv.weights(40))[1]
                       for _ in range(50)])
    assert (drawn == 0).float().mean() > 0.9  # e^3 / e^-3 = 403x as likely each
    plain = torch.cat([learner.policy_data.sample(8, gen)[1] for _ in range(50)])
    assert (plain == 0).float().mean() < 0.3  # without the weights: about 4 in 40
    with pytest.raises(ValueError, match=r"sample_weights: shape \(39,\), not \(40,\)"):
        learner.policy_data.sample(8, gen, None, adv.weights(39))


def test_a_resumed_learner_draws_and_weighs_as_the_uninterrupted_one(tmp_path) -> None:  # type: ignore[no-untyped-def]
    cfg = LearningConfig(**SMALL, weighting="advantage", advantage_refresh=3)
    whole = Learner(cfg, seed=3)
    _data(whole)
    for _ in range(4):
        whole.train_step()
    state = whole.training_state()
    assert "advantages" in state
    for _ in range(3):
        whole.train_step()
    resumed = Learner(cfg, seed=3)
    _data(resumed)
    resumed.load_training_state(state)
    for _ in range(3):
        resumed.train_step()
    a, b = whole.policy.state_dict(), resumed.policy.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert torch.equal(whole.advantages.advantage, resumed.advantages.advantage)  # type: ignore[union-attr]
    # an older checkpoint without the weights loads; the next refresh makes them
    del state["advantages"]
    old = Learner(cfg, seed=3)
    _data(old)
    old.load_training_state(state)
    assert old.advantages is not None and old.advantages.refreshes == 0


def test_the_value_critic_is_checkpointed_and_a_checkpoint_without_it_loads(tmp_path) -> None:  # type: ignore[no-untyped-def]
    plain = Learner(LearningConfig(**SMALL), seed=4)
    images, actions = _data(plain)
    plain.pretrain(transitions=None, steps=0)
    assert plain.value is None and "value" not in plain.state_dict()  # nobody asked for it
    plain.pretrain(images[:4], actions[:4], steps=1)
    theta0 = Learner(LearningConfig(**SMALL), seed=4)
    _data(theta0)
    theta0.pretrain(transitions=None, steps=0)
    from testbed.learning import Transitions

    t = Transitions.build(images[:10], actions[:10], images[1:11], np.zeros(10, bool),
                          np.arange(10) % 2 == 0)
    theta0.pretrain(transitions=t, steps=3, critics=["safety", "value"])
    assert theta0.value_updates == 3 and theta0.goal_updates == 0
    path = theta0.save(tmp_path / "theta0.pt")
    by_advantage = Learner.load(path, LearningConfig(**SMALL, weighting="advantage"))
    assert by_advantage.value_updates == 3
    a, b = theta0.value.net.state_dict(), by_advantage.value.net.state_dict()  # type: ignore[union-attr]
    assert all(torch.equal(a[k], b[k]) for k in a)
    plain_path = plain.save(tmp_path / "plain.pt")  # older checkpoints have no value critic
    fresh = Learner.load(plain_path, LearningConfig(**SMALL, weighting="advantage"))
    assert fresh.value is not None and fresh.value_updates == 0


def test_theta_0s_key_holds_the_value_horizon_only_when_it_pretrains_the_value_critic() -> None:
    from testbed.experiments.fleet_config import FleetConfig
    from testbed.experiments.pretraining import pretrain_key

    cfg = FleetConfig()
    other = cfg.model_copy(update={"learning": cfg.learning.model_copy(
        update={"gamma_value": 0.9, "weighting": "advantage", "advantage_temperature": 1.0})})
    assert pretrain_key(cfg, 0) == pretrain_key(other, 0)  # online-only for these critics
    assert pretrain_key(cfg, 0, ["safety", "value"]) != pretrain_key(other, 0,
                                                                     ["safety", "value"])
    assert pretrain_key(cfg, 0, ["safety", "value"]) != pretrain_key(cfg, 0, ["safety"])
