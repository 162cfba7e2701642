"""The Learner facade: outputs, input checks, determinism, checkpoints, thread safety."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from synthetic_pushing import transitions

from testbed.learning import Learner, LearningError, PolicyOutput, Transitions
from testbed.learning import checkpoint as ckpt
from testbed.learning.learning_config import LearningConfig

SMALL = LearningConfig(ensemble_size=2, batch_size=16, augmentation_factor=3, lr=1e-3,
                       gradient_steps=2, pretrain_steps=3)


def filled(seed: int = 0, cfg: LearningConfig = SMALL) -> Learner:
    learner = Learner(cfg, seed)
    rng = np.random.default_rng(seed)
    b = transitions(40, rng)
    learner.add_human(b.images[:20], b.actions[:20])
    learner.add_transitions(b.images, b.actions, b.next_images, b.violation, b.success)
    return learner


def params(learner: Learner) -> list[torch.Tensor]:
    mods = [learner.policy, learner.safety.net, learner.safety.target, learner.goal.net,
            learner.goal.target]
    return [p.detach().clone() for m in mods for p in m.parameters()]


def same(a: list[torch.Tensor], b: list[torch.Tensor]) -> bool:
    return len(a) == len(b) and all(torch.equal(x, y) for x, y in zip(a, b, strict=True))


def test_act_shapes_and_ranges() -> None:
    learner = filled()
    images = transitions(6, np.random.default_rng(1)).images
    out = learner.act(images)
    assert isinstance(out, PolicyOutput) and len(out) == 6
    assert out.actions.dtype == np.int64 and out.actions.shape == (6,)
    assert out.probs.shape == (6, 4) and np.allclose(out.probs.sum(1), 1, atol=1e-5)
    assert (out.actions == out.probs.argmax(1)).all()
    for name in ("uncertainty", "risk", "goal_risk", "novelty"):
        v = getattr(out, name)
        assert v.shape == (6,) and v.dtype == np.float32
        assert ((v >= 0) & (v <= 1)).all(), name
    assert len(learner.act(np.zeros((0, 64, 64, 3), np.uint8))) == 0
    assert len(learner.act(images[0])) == 1  # a single (64, 64, 3) image


def test_inputs_are_validated() -> None:
    learner = Learner(SMALL, 0)
    with pytest.raises(ValueError, match="uint8"):
        learner.act(np.zeros((1, 64, 64, 3), np.float32))
    with pytest.raises(ValueError, match="shape"):
        learner.act(np.zeros((1, 32, 32, 3), np.uint8))
    with pytest.raises(ValueError, match=r"\[0, 4\)"):
        learner.add_human(np.zeros((1, 64, 64, 3), np.uint8), [4])
    with pytest.raises(ValueError, match="expected 2 values"):
        learner.add_human(np.zeros((2, 64, 64, 3), np.uint8), [1])
    with pytest.raises(ValueError, match="next_images"):
        Transitions.build(np.zeros((2, 64, 64, 3), np.uint8), [0, 1],
                          np.zeros((1, 64, 64, 3), np.uint8), [0, 0], [0, 0])


def test_train_step_trains_what_has_data() -> None:
    learner = Learner(SMALL, 0)
    assert learner.train_step() == {} and not learner.has_data
    b = transitions(20, np.random.default_rng(0))
    learner.add_transitions(b.images, b.actions, b.next_images, b.violation, b.success)
    assert set(learner.train_step()) == {"safety_loss", "goal_loss"}
    learner.add_human(b.images, b.actions)
    assert learner.has_data
    assert set(learner.train_step()) == {"policy_loss", "safety_loss", "goal_loss"}
    stats = learner.stats()
    assert stats["human_samples"] == 20 and stats["transitions"] == 20
    assert stats["policy_updates"] == 2 and stats["critic_updates"] == 4  # gradient_steps 2


def test_same_seed_same_weights_different_seed_different() -> None:
    a, b, c = filled(0), filled(0), filled(0, SMALL)
    c2 = Learner(SMALL, 1)
    assert same(params(a), params(b))
    assert not same(params(a), params(c2))
    for learner in (a, b):
        learner.train_step()
        learner.train_step()
    assert same(params(a), params(b))
    assert not same(params(a), params(c))  # c did not train


def test_global_torch_rng_untouched() -> None:
    torch.manual_seed(123)
    expected = torch.rand(3)
    torch.manual_seed(123)
    Learner(SMALL, 5)
    assert torch.equal(torch.rand(3), expected)


def test_save_load_round_trip_continues_exactly(tmp_path: Path) -> None:
    learner = filled()
    learner.train_step()
    path = learner.save(tmp_path / "ckpt.pt")
    loaded = Learner.load(path)
    images = transitions(8, np.random.default_rng(2)).images
    a, b = learner.act(images), loaded.act(images)
    for name in ("actions", "probs", "uncertainty", "risk", "goal_risk", "novelty"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert loaded.stats() == learner.stats()
    # the data, the optimisers and the sampler state came along: training continues alike
    more = transitions(5, np.random.default_rng(3))
    for x in (learner, loaded):
        x.add_human(more.images, more.actions)
        x.train_step()
    assert same(params(learner), params(loaded))
    assert [p.name for p in tmp_path.iterdir()] == ["ckpt.pt"]  # no temp file left


def test_snapshot_is_the_state_now_whatever_training_does_next(tmp_path: Path) -> None:
    """The checkpoint's snapshot (the training state: no data) shares no tensor with the
    learner: written while training and data go on, it holds the step it was taken at,
    and restores it onto a learner holding that step's data, and no other."""
    learner = filled()
    learner.train_step()
    snap = learner.training_state()
    assert "policy_data" not in snap and "transitions" not in snap
    ckpt.save_atomic(learner.state_dict(), tmp_path / "now.pt")
    more = transitions(5, np.random.default_rng(4))
    learner.add_human(more.images, more.actions)
    learner.add_transitions(more.images, more.actions, more.next_images, more.violation,
                            more.success)
    learner.train_step()
    ckpt.save_atomic(snap, tmp_path / "snap.pt")
    a, b = Learner.load(tmp_path / "now.pt"), Learner.load(tmp_path / "now.pt")
    b.train_step()  # b moves on; the snapshot takes it back to the step
    assert not same(params(a), params(b))
    b.load_training_state(ckpt.load(tmp_path / "snap.pt", ckpt.TRAINING_FORMAT))
    assert same(params(a), params(b))
    assert a.stats() == b.stats() != learner.stats()
    opt_a = a.policy_optimizer.state_dict()["state"]
    opt_b = b.policy_optimizer.state_dict()["state"]
    assert all(torch.equal(opt_a[k]["exp_avg"], opt_b[k]["exp_avg"]) for k in opt_a)
    assert a.train_step() == b.train_step()  # the sampler too
    with pytest.raises(LearningError, match="data"):  # the learner now has more data
        learner.load_training_state(ckpt.load(tmp_path / "snap.pt", ckpt.TRAINING_FORMAT))


def test_load_checks_the_shape_defining_config(tmp_path: Path) -> None:
    path = filled().save(tmp_path / "c.pt")
    with pytest.raises(LearningError, match="ensemble_size"):
        Learner.load(path, SMALL.model_copy(update={"ensemble_size": 3}))
    loaded = Learner.load(path, SMALL.model_copy(update={"lr": 1e-4, "batch_size": 8}))
    assert loaded.policy_optimizer.param_groups[0]["lr"] == 1e-4
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(Exception):  # noqa: B017 - torch's own unpickling error
        Learner.load(tmp_path / "junk.pt")


def test_failed_save_keeps_the_old_checkpoint(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    learner = filled()
    path = learner.save(tmp_path / "c.pt")
    before = path.read_bytes()

    def broken(*args: object, **kwargs: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(ckpt.torch, "save", broken)
    learner.train_step()
    with pytest.raises(OSError, match="disk full"):
        learner.save(path)
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["c.pt"]


def test_pretrain_reports_progress_in_phases() -> None:
    learner = Learner(SMALL, 0)
    b = transitions(30, np.random.default_rng(0))
    seen: list[tuple[str, int, int]] = []
    t = Transitions.build(b.images, b.actions, b.next_images, b.violation, b.success)
    out = learner.pretrain(b.images, b.actions, t, progress=lambda *a: seen.append(a))
    assert seen == [("policy", i, 3) for i in (1, 2, 3)] + [("critics", i, 3) for i in (1, 2, 3)]
    assert set(out) == {"policy_loss", "safety_loss", "goal_loss"}
    assert learner.stats()["policy_updates"] == 3 and learner.stats()["critic_updates"] == 3
    with pytest.raises(ValueError, match="together"):
        learner.pretrain(b.images, None)


def test_critics_take_their_own_pretrain_steps() -> None:
    """``critic_pretrain_steps`` sets the critics' phase alone; an explicit ``steps``
    argument still sets both phases."""
    learner = Learner(SMALL.model_copy(update={"critic_pretrain_steps": 5}), 0)
    b = transitions(30, np.random.default_rng(0))
    t = Transitions.build(b.images, b.actions, b.next_images, b.violation, b.success)
    seen: list[tuple[str, int, int]] = []
    learner.pretrain(b.images, b.actions, t, progress=lambda *a: seen.append(a))
    assert [s for s in seen if s[0] == "policy"][-1] == ("policy", 3, 3)
    assert [s for s in seen if s[0] == "critics"][-1] == ("critics", 5, 5)
    assert learner.stats()["policy_updates"] == 3 and learner.stats()["critic_updates"] == 5
    learner.pretrain(transitions=t, steps=2)
    assert learner.stats()["critic_updates"] == 7


def test_concurrent_calls_are_serialised() -> None:
    learner = filled()
    images = transitions(4, np.random.default_rng(1)).images
    errors: list[BaseException] = []

    def train() -> None:
        try:
            for _ in range(3):
                learner.train_step()
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    thread = threading.Thread(target=train)
    thread.start()
    for _ in range(5):
        assert len(learner.act(images)) == 4
    thread.join()
    assert not errors


def test_cuda_request_without_cuda_is_a_clear_error() -> None:
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    with pytest.raises(LearningError, match="device"):
        Learner(SMALL.model_copy(update={"device": "cuda"}), 0)


def test_import_testbed_does_not_import_torch() -> None:
    code = ("import sys, testbed, testbed.core.config, testbed.core.types; "
            "sys.exit(1 if 'torch' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


def test_loop_and_vmap_compute_the_same() -> None:
    loop, vmap = filled(0), Learner(SMALL, 0, impl="vmap")
    assert loop.impl == "loop" and vmap.impl == "vmap"
    b = transitions(40, np.random.default_rng(0))
    vmap.add_human(b.images[:20], b.actions[:20])
    vmap.add_transitions(b.images, b.actions, b.next_images, b.violation, b.success)
    images = transitions(5, np.random.default_rng(4)).images
    assert np.allclose(loop.act(images).probs, vmap.act(images).probs, atol=1e-6)
    a, v = loop.train_step(), vmap.train_step()
    assert a.keys() == v.keys()
    assert all(abs(a[k] - v[k]) < 1e-4 for k in a)
    for p, q in zip(params(loop), params(vmap), strict=True):
        assert torch.allclose(p, q, atol=1e-5)


def test_no_gradient_steps_is_a_no_op() -> None:
    learner = filled(0, SMALL.model_copy(update={"gradient_steps": 0}))
    before = params(learner)
    assert learner.train_step() == {}
    assert same(before, params(learner))


def test_reseed_keeps_weights_and_makes_trials_distinct(tmp_path: Path) -> None:
    theta0 = filled(0).save(tmp_path / "theta0.pt")
    more = transitions(6, np.random.default_rng(5))
    runs = {}
    for name, seed in (("a", 11), ("b", 11), ("c", 12)):
        learner = Learner.load(theta0)
        learner.reseed(seed)
        learner.add_human(more.images, more.actions)
        learner.train_step()
        runs[name] = learner
    assert same(params(runs["a"]), params(runs["b"]))
    assert not same(params(runs["a"]), params(runs["c"]))
    # a reseeded learner's checkpoint resumes exactly (the chunks keep their own seeds)
    resumed = Learner.load(runs["a"].save(tmp_path / "a.pt"))
    for x in (runs["a"], resumed):
        x.train_step()
    assert same(params(runs["a"]), params(resumed))


def test_remade_copies_are_checked(tmp_path: Path) -> None:
    learner = filled(0)
    state = learner.state_dict()
    state["policy_data"]["chunks"][0][2] = "0" * 32
    ckpt.save_atomic(state, tmp_path / "tampered.pt")
    with pytest.warns(RuntimeWarning, match="not bit-exact"):
        Learner.load(tmp_path / "tampered.pt")


def test_loads_checkpoints_that_stored_chunk_sizes_only(tmp_path: Path) -> None:
    from testbed.learning.data import _digest

    learner = filled(0)
    state = learner.state_dict()
    data = state["policy_data"]
    data["chunks"] = [c[0] for c in data["chunks"]]  # the first format: sizes, one digest
    data["digest"] = _digest(learner.policy_data._store["images"])
    ckpt.save_atomic(state, tmp_path / "v1.pt")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loaded = Learner.load(tmp_path / "v1.pt")
    for x in (learner, loaded):
        x.train_step()
    assert same(params(learner), params(loaded))


def test_training_state_into_an_old_one_reuses_its_tensors_and_equals_a_fresh_one() -> None:
    learner = Learner(SMALL, seed=0)
    empty = learner.training_state()  # before any step: the optimisers hold no moments
    data = transitions(8, np.random.default_rng(1))
    learner.add_human(data.images, data.actions)
    learner.add_transitions(data.images, data.actions, data.next_images, data.violation,
                            data.success)
    learner.train_step()
    first = learner.training_state(into=empty)  # another layout: a fresh copy
    assert first is not empty and first["policy_optimizer"]["state"]
    counters = list(first["counters"])
    learner.train_step()
    again = learner.training_state(into=first)
    assert again is first  # the same tensors, overwritten in place
    fresh = learner.training_state()
    for part in ("policy", "safety", "goal"):
        flat_a, flat_b = again[part], fresh[part]
        for k, v in flat_b.items():
            if isinstance(v, torch.Tensor):
                assert torch.equal(flat_a[k], v), (part, k)
    assert torch.equal(again["sampler"], fresh["sampler"])
    assert again["counters"] == fresh["counters"] != counters
    assert again["data_sizes"] == fresh["data_sizes"]
    p = next(iter(learner.policy.parameters()))
    with torch.no_grad():
        p.add_(1.0)  # the learner's weights move on; the snapshot does not
    assert not torch.equal(learner.training_state()["policy"][next(iter(fresh["policy"]))],
                           again["policy"][next(iter(fresh["policy"]))])


def test_who_gave_each_label_is_kept_saved_and_loaded(tmp_path: Path) -> None:
    """The labeller reaches the learner with every label (``records.store.add_labels``
    passes the frame's human), is kept beside it through a checkpoint as one code per
    person, and changes no number: a learner given the same labels without their
    labellers trains the same."""
    rng = np.random.default_rng(3)
    b = transitions(12, rng)
    with_who, without = Learner(SMALL, 5), Learner(SMALL, 5)
    with_who.add_human(b.images[:4], b.actions[:4])  # an offline demonstration: no human
    with_who.add_human(b.images[4:], b.actions[4:], labellers=[1, 0, 0, 1, 0, 0, 1, 0])
    without.add_human(b.images[:4], b.actions[:4])
    without.add_human(b.images[4:], b.actions[4:])
    # the fleet's human index, unnamed: one code per person, in the order first seen
    assert with_who.labellers.tolist() == [-1] * 4 + [0, 1, 1, 0, 1, 1, 0, 1]
    assert with_who.labeller_names == ["human1", "human0"]
    assert without.labellers.tolist() == [-1] * 12 and without.labeller_names == []
    with_who.train_step()
    without.train_step()
    assert same(params(with_who), params(without))
    loaded = Learner.load(with_who.save(tmp_path / "who.pt"))
    assert loaded.labellers.tolist() == with_who.labellers.tolist()
    assert loaded.labeller_names == with_who.labeller_names
    with pytest.raises(ValueError, match="3 labellers for 2 labels"):
        with_who.add_human(b.images[:2], b.actions[:2], labellers=[0, 1, 1])
    state = with_who.policy_data.state_dict()
    del state["labeller_names"]  # a checkpoint before names: codes were human indices
    state["labellers"] = torch.tensor([-1] * 4 + [1, 0, 0, 1, 0, 0, 1, 0], dtype=torch.int16)
    assert with_who.policy_data.load_state_dict(state)
    assert [with_who.labeller_names[c] if c >= 0 else None for c in with_who.labellers] \
        == [None] * 4 + [f"human{h}" for h in (1, 0, 0, 1, 0, 0, 1, 0)]
    del state["labellers"]  # a checkpoint written before labellers were kept
    assert with_who.policy_data.load_state_dict(state)
    assert with_who.labellers.tolist() == [-1] * 12


def test_labellers_with_names_are_one_code_per_person(tmp_path: Path) -> None:
    """Labels given with their people's names (a merged export's): one code per name,
    whatever index each batch gave it; the names survive a checkpoint."""
    rng = np.random.default_rng(4)
    b = transitions(6, rng)
    learner = Learner(SMALL, 5)
    learner.add_human(b.images[:3], b.actions[:3], labellers=[0, 1, -1], names=["ana", "bo"])
    learner.add_human(b.images[3:], b.actions[3:], labellers=[1, 0, 0], names=["cy", "ana"])
    assert learner.labeller_names == ["ana", "bo", "cy"]
    assert learner.labellers.tolist() == [0, 1, -1, 0, 2, 2]
    loaded = Learner.load(learner.save(tmp_path / "named.pt"))
    assert loaded.labeller_names == ["ana", "bo", "cy"]
    assert loaded.labellers.tolist() == learner.labellers.tolist()
    with pytest.raises(ValueError, match="labeller 2 has no name"):
        learner.add_human(b.images[:1], b.actions[:1], labellers=[2], names=["ana", "bo"])


def test_a_learner_told_the_runs_people_keeps_the_loops_labels_by_name(
        tmp_path: Path) -> None:
    """The loop gives labels by human index; a learner told the run's people
    (``name_fleet``, as the trial and a resume do) keeps them by name. It is not saved:
    loaded into another run, index 0 is whoever that run says."""
    rng = np.random.default_rng(5)
    b = transitions(6, rng)
    learner = Learner(SMALL, 5)
    learner.name_fleet(["ana", "human1"])  # human1: a name the config did not give
    learner.add_human(b.images[:3], b.actions[:3], labellers=[1, 0, 1])
    assert learner.labeller_names == ["human1", "ana"]
    again = Learner.load(learner.save(tmp_path / "run1.pt"))
    again.name_fleet(["cy", "ana"])  # the next run: ana is index 1 there
    again.add_human(b.images[3:], b.actions[3:], labellers=[1, 0, 1])
    assert again.labeller_names == ["human1", "ana", "cy"]
    assert again.labellers.tolist() == [0, 1, 0, 1, 2, 1]
