"""Learning by class (issue 30): ``learning.weighting = "intervention"``.

The learner is the real one (small: 2 members, batch 8, 2 copies); the fleet loop and the
data store are the real ones, over a deterministic fake world whose arms succeed, time
out and violate, so every class and outcome reaches the learner.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from testbed.core.types import (
    IMAGE_SIZE,
    ArmObservation,
    EpisodeOutcome,
    FrameClass,
    PushResult,
)
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import get_algorithm
from testbed.fleet.loop import FleetLoop
from testbed.learning import Learner
from testbed.learning.data import PolicyData
from testbed.learning.learner import class_table
from testbed.learning.learning_config import ClassWeights, LearningConfig
from testbed.records import store as rundata
from testbed.records.frame_classes import classify
from testbed.records.steps import RunWriter
from testbed.records.store import RunData, RunDataWriter

ARMS = ["a/l", "a/r", "b/l", "b/r"]
SMALL = {"ensemble_size": 2, "batch_size": 8, "augmentation_factor": 2}


def _cfg(weighting: str = "intervention", **weights: float) -> LearningConfig:
    return LearningConfig(**SMALL, weighting=weighting, pre_intervention_steps=2,
                          class_weights=ClassWeights(**weights))


def _images(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, IMAGE_SIZE, IMAGE_SIZE, 3),
                                                dtype=np.uint8)


def _same_weights(a: Learner, b: Learner) -> bool:
    sa, sb = a.policy.state_dict(), b.policy.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


class _World:
    """Each arm's pushes roll a die seeded by (arm, pushes so far): the expert's face
    moves the cube on, 3 good pushes in a row succeed (a new goal), a roll of 0 violates
    (idle until a reset, then a new goal), 6 pushes without success time out (a new goal)."""

    def __init__(self) -> None:
        self.robot_names = list(ARMS)
        self.pushes = dict.fromkeys(ARMS, 0)
        self.good = dict.fromkeys(ARMS, 0)
        self.tries = dict.fromkeys(ARMS, 0)
        self.goals = dict.fromkeys(ARMS, 0)
        self.violating = dict.fromkeys(ARMS, False)

    def observe(self) -> dict[str, ArmObservation]:
        out = {}
        for k, r in enumerate(ARMS):
            img = np.random.default_rng([k, self.pushes[r], self.goals[r]]).integers(
                0, 256, (IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
            goal = (0.1 + 0.1 * (self.goals[r] % 8), 0.5)
            out[r] = ArmObservation(r, img, self.violating[r], goal, (k + self.pushes[r]) % 4)
        return out

    def execute(self, pushes: Mapping[str, int], resets: Sequence[str]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k, r in enumerate(ARMS):
            if r in resets:
                self.violating[r], self.goals[r], self.good[r], self.tries[r] = False, \
                    self.goals[r] + 1, 0, 0
            if r not in pushes:
                out[r] = PushResult(r, None, False, False)
                continue
            expert = (k + self.pushes[r]) % 4
            roll = int(np.random.default_rng([k, self.pushes[r], 7]).integers(0, 9))
            self.pushes[r] += 1
            self.tries[r] += 1
            violation = roll == 0
            self.good[r] = self.good[r] + 1 if pushes[r] == expert or roll > 5 else 0
            success = not violation and self.good[r] >= 3
            if violation:
                self.violating[r] = True
            elif success or self.tries[r] >= 6:
                self.goals[r] += 1
                self.good[r] = self.tries[r] = 0
            out[r] = PushResult(r, pushes[r], success, violation)
        return out


def _algorithm() -> Any:
    return get_algorithm("fleet-ed", AlgorithmConfig(t_I=0, u_hat=0.0, t_T=2, t_R=2), 4, 1, 5)


def _run(folder: Path, learner: Learner, world: _World, algorithm: Any, span: range,
         session: int, after: Any = None) -> None:
    """The fleet loop over steps ``span`` (a resume when it does not start at 0)."""
    data = RunDataWriter(folder, ARMS, keep_steps=span.start)
    with RunWriter(folder) as writer:
        loop = FleetLoop(hosts=world, humans=ScriptedHumans(), learner=learner,
                         algorithm=algorithm, writer=writer, steps=span.stop, num_humans=1,
                         t_T=2, t_R=2, data=data, session=session, after_step=after)
        if span.start:
            loop.restore_feed(f for _, f in RunData.of_run(folder).iter_steps(0, span.start))
        for t in span:
            loop.step(t)
        loop.close()
    data.close()


def _start(seed: int = 11, **weights: float) -> Learner:
    learner = Learner(_cfg(**weights), seed=seed, train={"policy"}, read=())
    learner.add_human(_images(6, 1), np.arange(6) % 4)  # the "demonstrations"
    return learner


def test_the_loop_feeds_robot_pushes_by_class_and_a_resume_rebuilds_the_same_learner(
        tmp_path: Path) -> None:
    steps, cut = 30, 13
    whole = _start()
    _run(tmp_path / "whole", whole, _World(), _algorithm(), range(steps), 0)
    classes, outcomes = whole.label_classes()
    fed = set(zip(classes.tolist(), outcomes.tolist(), strict=True))
    assert (FrameClass.ROBOT, EpisodeOutcome.SUCCESS) in fed  # the robot's good pushes
    assert (FrameClass.TELEOP, EpisodeOutcome.OPEN) in fed  # labels, as they come
    assert any(c == FrameClass.PRE_INTERVENTION for c, _ in fed)  # kept at its weight
    assert all(c in (FrameClass.DEMO, FrameClass.TELEOP, FrameClass.PRE_INTERVENTION) or (
        c == FrameClass.ROBOT and o == EpisodeOutcome.SUCCESS) for c, o in fed), fed
    # exactly the robot frames that classify() finds in the store and the weights keep:
    # ROBOT in succeeded episodes, PRE_INTERVENTION in any (robot_failed is 0)
    got = classify(RunData.of_run(tmp_path / "whole").frames(), len(ARMS), 2)
    want = (got.classes == FrameClass.ROBOT) & (got.outcomes == EpisodeOutcome.SUCCESS)
    pre = (got.classes == FrameClass.PRE_INTERVENTION) & (got.outcomes != EpisodeOutcome.OPEN)
    assert int(np.count_nonzero(classes == FrameClass.ROBOT)) == int(want.sum()) > 0
    assert int(np.count_nonzero(classes == FrameClass.PRE_INTERVENTION)) == int(pre.sum()) > 0

    # the same run stopped after step cut - 1 and resumed: the learner rebuilt the way
    # a resume does (start, data replayed, the step's training state), the loop's open
    # episodes from the store; it ends with the unbroken run's data and weights
    world, broken, algorithm = _World(), _start(), _algorithm()
    saved: dict[str, Any] = {}

    def keep(t: int) -> None:
        if t == cut - 1:
            saved["learner"] = broken.training_state()
            saved["algorithm"] = algorithm.state_dict()

    _run(tmp_path / "broken", broken, world, algorithm, range(cut), 0, after=keep)
    rebuilt = _start()
    rundata.replay(rebuilt, RunData.of_run(tmp_path / "broken"), cut)
    rebuilt.load_training_state(saved["learner"])
    assert _same_weights(rebuilt, broken)
    again = _algorithm()
    again.load_state_dict(saved["algorithm"])
    _run(tmp_path / "broken", rebuilt, world, again, range(cut, steps), 1)
    assert rebuilt.data_sizes()["policy"] == whole.data_sizes()["policy"]
    assert np.array_equal(rebuilt.label_classes()[0], classes)
    assert _same_weights(rebuilt, whole)


def test_unit_weights_on_human_labels_only_draw_todays_samples() -> None:
    """``intervention`` with demo = teleop = 1 and the robot's pushes at 0 is uniform."""
    today = Learner(_cfg("uniform"), seed=3, train={"policy"}, read=())
    same = Learner(_cfg(demo=1.0, teleop=1.0, robot=0.0, pre_intervention=0.0,
                        robot_failed=0.0), seed=3, train={"policy"}, read=())
    for learner in (today, same):
        learner.add_human(_images(10, 1), np.arange(10) % 4)
        learner.add_human(_images(5, 2), np.arange(5) % 4, labellers=np.array([0, 1, 0, 1, 0]))
        learner.add_robot(_images(4, 3), np.zeros(4, np.int64), np.full(4, FrameClass.ROBOT),
                          np.full(4, EpisodeOutcome.SUCCESS))
        for _ in range(4):
            learner.train_step()
    assert today.data_sizes() == same.data_sizes()
    assert _same_weights(today, same)
    assert today._sampler.get_state().equal(same._sampler.get_state())


def test_pretraining_is_the_same_whatever_the_weighting() -> None:
    """theta_0 does not depend on the weighting: every way of a protocol shares it."""
    a = Learner(_cfg("uniform"), seed=4, train={"policy"}, read=())
    b = Learner(_cfg(demo=7.0), seed=4, train={"policy"}, read=())
    for learner in (a, b):
        learner.pretrain(_images(12, 5), np.arange(12) % 4, steps=3)
    assert _same_weights(a, b)


def test_members_draw_in_proportion_to_class_weight_times_bootstrap() -> None:
    data = PolicyData(ensemble_size=2, factor=1, seed=0)
    n = 200
    data.add(_images(n, 6), np.zeros(n, np.int64), classes=np.repeat(
        [FrameClass.TELEOP, FrameClass.ROBOT, FrameClass.PRE_INTERVENTION], [n // 2, n // 4,
                                                                            n - 3 * n // 4]),
             outcomes=np.full(n, EpisodeOutcome.SUCCESS))
    table = class_table(ClassWeights(teleop=3.0, robot=1.0, pre_intervention=0.0))
    gen = torch.Generator().manual_seed(0)
    counts = np.zeros(3)
    classes = data.classes()[0]
    for _ in range(50):
        images, _ = data.sample(256, gen, table)
        # which sample each draw took: its image is unique (factor 1: the original)
        flat = images.reshape(-1, IMAGE_SIZE * IMAGE_SIZE * 3)[:, :16]
        originals = torch.from_numpy(data.originals().reshape(n, -1)[:, :16])
        which = (flat[:, None, :] == originals[None]).all(-1).float().argmax(1).numpy()
        for j, c in enumerate((FrameClass.TELEOP, FrameClass.ROBOT,
                               FrameClass.PRE_INTERVENTION)):
            counts[j] += np.count_nonzero(classes[which] == c)
    weights = data.state_dict()["weights"].numpy()
    mass = [3.0 * weights[: n // 2].sum(), weights[n // 2 : 3 * n // 4].sum(), 0.0]
    assert counts[2] == 0  # weight 0: never drawn
    assert counts[0] / counts[1] == pytest.approx(mass[0] / mass[1], rel=0.08)


def test_add_robot_keeps_only_what_its_class_weight_counts() -> None:
    learner = _start(robot=1.0, pre_intervention=0.5, robot_failed=0.0)
    before = learner.data_sizes()["policy"]
    learner.add_robot(_images(4, 9), np.arange(4),
                      [FrameClass.ROBOT, FrameClass.ROBOT, FrameClass.PRE_INTERVENTION,
                       FrameClass.ROBOT],
                      [EpisodeOutcome.SUCCESS, EpisodeOutcome.VIOLATION,
                       EpisodeOutcome.VIOLATION, EpisodeOutcome.GOAL_CHANGE])
    classes, outcomes = learner.label_classes()
    assert learner.data_sizes()["policy"] == before + 2
    assert classes[-2:].tolist() == [FrameClass.ROBOT, FrameClass.PRE_INTERVENTION]
    assert outcomes[-2:].tolist() == [EpisodeOutcome.SUCCESS, EpisodeOutcome.VIOLATION]
    uniform = Learner(_cfg("uniform"), seed=1)
    uniform.add_robot(_images(1, 9), [0], [FrameClass.ROBOT], [EpisodeOutcome.SUCCESS])
    assert uniform.data_sizes()["policy"] == 0 and not uniform.robot_frames
    with pytest.raises(ValueError, match="2 classes"):
        learner.add_robot(_images(1, 9), [0], [1, 1], [1])
