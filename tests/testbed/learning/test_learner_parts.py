"""Train only what the algorithm reads (issue 13): per-part training, act and pretraining.

Every algorithm's learner is set up as the trial sets it (``AlgorithmSpec.train_parts``
and ``critics``), trained, and its per-part update counters and weights are checked: a
part the algorithm does not read is never updated, and the critics' targets share one
policy forward pass (none when no critic trains).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from synthetic_pushing import transitions

from testbed.experiments.pretraining import CRITICS as OFFLINE_CRITICS
from testbed.fleet.algorithms import ALGORITHMS
from testbed.fleet.priorities import CRITIC_OF_SIGNAL
from testbed.learning import Learner, Transitions
from testbed.learning import checkpoint as ckpt
from testbed.learning.learner import CRITICS, DEFAULT_PARTS, PARTS
from testbed.learning.learning_config import LearningConfig

SMALL = LearningConfig(ensemble_size=2, batch_size=16, augmentation_factor=2, lr=1e-3,
                       gradient_steps=2, pretrain_steps=3)


def data() -> Transitions:
    b = transitions(30, np.random.default_rng(0))
    return Transitions.build(b.images, b.actions, b.next_images, b.violation, b.success)


def filled(**parts: object) -> Learner:
    learner = Learner(SMALL, 0, **parts)  # type: ignore[arg-type]
    t = data()
    learner.add_human(t.images[:20], t.actions[:20])
    learner.add_transitions(t.images, t.actions, t.next_images, t.violation, t.success)
    return learner


def weights(learner: Learner) -> dict[str, list[torch.Tensor]]:
    mods = {"policy": [learner.policy], "safety": [learner.safety.net, learner.safety.target],
            "goal": [learner.goal.net, learner.goal.target]}
    return {k: [p.detach().clone() for m in ms for p in m.parameters()]
            for k, ms in mods.items()}


def same(a: list[torch.Tensor], b: list[torch.Tensor]) -> bool:
    return all(torch.equal(x, y) for x, y in zip(a, b, strict=True))


def counts(learner: Learner) -> dict[str, int]:
    s = learner.stats()
    return {"policy": s["policy_updates"], "safety": s["safety_updates"],
            "goal": s["goal_updates"]}


def test_the_names_agree_everywhere() -> None:
    assert CRITICS == OFFLINE_CRITICS == ("safety", "goal")
    assert set(CRITIC_OF_SIGNAL.values()) == set(CRITICS)
    assert PARTS[0] == "policy" and PARTS[1:] == (*CRITICS, "value")
    assert ("policy", *CRITICS) == DEFAULT_PARTS  # the value critic only where asked


def test_what_each_algorithm_trains() -> None:
    parts = {name: spec.train_parts for name, spec in ALGORITHMS.items()}
    assert parts["cur"] == parts["cur-i"] == {"policy", "safety"}
    assert parts["fleet-td"] == {"policy", "goal"}
    assert parts["fleet-ed"] == parts["random"] == {"policy"}
    assert parts["bc"] == frozenset()
    assert ALGORITHMS["bc"].critics == ALGORITHMS["fleet-ed"].critics == frozenset()
    for ablation in ("r", "cr", "ur", "ru", "cru"):
        assert parts[ablation] == {"policy", "safety"}
    for ablation in ("c", "u", "cu", "uc"):
        assert parts[ablation] == {"policy"}


@pytest.mark.parametrize("name", ["cur", "fleet-td", "fleet-ed", "bc"])
def test_an_algorithm_never_trains_a_part_it_does_not_read(name: str) -> None:
    spec = ALGORITHMS[name]
    learner = filled(train=spec.train_parts, read=spec.critics)
    before = weights(learner)
    losses = learner.train_step()
    losses.update(learner.train_step())
    after = weights(learner)
    steps = 2 * SMALL.gradient_steps
    assert counts(learner) == {p: steps if p in spec.train_parts else 0 for p in DEFAULT_PARTS}
    assert set(losses) == {f"{p}_loss" for p in spec.train_parts}
    for part in DEFAULT_PARTS:
        assert same(before[part], after[part]) == (part not in spec.train_parts), part
    assert learner.stats()["critic_updates"] == (steps if spec.critics else 0)


def test_the_critics_share_one_policy_forward_and_skip_it_when_none_trains() -> None:
    calls: list[int] = []
    for train in (DEFAULT_PARTS, ("policy", "safety"), ("policy", "goal"), ("policy",), ("safety",),
                  ()):
        learner = filled(train=train)
        hook = learner.policy.register_forward_hook(lambda *_: calls.append(1))
        calls.clear()
        learner.train_step()  # gradient_steps 2
        hook.remove()
        per_step = ("policy" in train) + any(c in train for c in CRITICS)
        assert len(calls) == 2 * per_step, train


def test_act_computes_only_the_critics_read() -> None:
    images = data().images[:6]
    full = filled().act(images)
    for read in ((), ("safety",), ("goal",)):
        learner = filled(read=read)
        for critic in set(CRITICS) - set(read):  # never evaluated
            getattr(learner, critic).values = None
        out = learner.act(images)
        np.testing.assert_array_equal(out.actions, full.actions)
        np.testing.assert_array_equal(out.uncertainty, full.uncertainty)
        for critic, signal in (("safety", "risk"), ("goal", "goal_risk")):
            value = getattr(out, signal)
            assert value.dtype == np.float32 and value.shape == (6,)
            if critic in read:
                np.testing.assert_array_equal(value, getattr(full, signal))
            else:
                np.testing.assert_array_equal(value, np.zeros(6, np.float32))


def test_set_parts_checks_the_names() -> None:
    learner = Learner(SMALL, 0)
    assert learner.train_parts == set(DEFAULT_PARTS) and learner.read_critics == set(CRITICS)
    with pytest.raises(ValueError, match="unknown part"):
        learner.set_parts(train=["policy", "values"])
    with pytest.raises(ValueError, match="unknown part"):
        learner.set_parts(read=["value"])  # act reads no value critic
    with pytest.raises(ValueError, match="unknown part"):
        learner.set_parts(read=["policy"])  # the policy is always read
    with pytest.raises(TypeError, match="string"):
        learner.set_parts(train="policy")
    learner.set_parts(train=["goal"], read=[])
    assert learner.train_parts == {"goal"} and learner.read_critics == frozenset()


def test_pretrain_trains_only_the_critics_given_on_the_same_minibatches() -> None:
    t = data()
    results = {}
    for critics in (None, ("safety",), ()):
        learner = Learner(SMALL, 0)
        seen: list[tuple[str, int, int]] = []
        out = learner.pretrain(t.images, t.actions, t, progress=lambda *a, s=seen: s.append(a),
                               critics=critics)
        which = CRITICS if critics is None else critics
        assert counts(learner) == {"policy": 3, **{c: 3 if c in which else 0 for c in CRITICS}}
        assert set(out) == {"policy_loss", *(f"{c}_loss" for c in which)}
        assert [s[0] for s in seen].count("critics") == (3 if which else 0)
        assert len(learner.transitions) == len(t)  # added even when no critic trains
        results[critics] = weights(learner)
    both, safety, none = results[None], results[("safety",)], results[()]
    assert same(both["policy"], safety["policy"]) and same(both["policy"], none["policy"])
    assert same(both["safety"], safety["safety"])  # the goal critic's absence changes nothing
    fresh = weights(Learner(SMALL, 0))
    assert same(safety["goal"], fresh["goal"]) and same(none["safety"], fresh["safety"])
    with pytest.raises(ValueError, match="critics: unknown part"):
        Learner(SMALL, 0).pretrain(transitions=t, critics=["policy"])


def test_per_part_counters_are_checkpointed_and_old_checkpoints_load(tmp_path: Path) -> None:
    learner = filled(train=("policy", "goal"))
    learner.train_step()
    path = learner.save(tmp_path / "a.pt")
    loaded = Learner.load(path, train=("policy",), read=())
    assert counts(loaded) == counts(learner) == {"policy": 2, "safety": 0, "goal": 2}
    assert loaded.train_parts == {"policy"} and loaded.read_critics == frozenset()
    assert Learner.load(path).train_parts == set(DEFAULT_PARTS)  # parts are not saved
    state = ckpt.load(path)
    state["counters"] = [5, 7]  # the first format: every critic step trained both
    ckpt.save_atomic(state, tmp_path / "old.pt")
    old = Learner.load(tmp_path / "old.pt")
    assert counts(old) == {"policy": 5, "safety": 7, "goal": 7}
    assert old.stats()["critic_updates"] == 7
