"""Training beside act (``FleetLoop`` with ``Learner.acting_copy()``) records what the serial order
(act, then train) records, and leaves the learner in the same state.

A real (small) learner on fake hosts whose pictures and outcomes are a seeded function
of the step and the push, so both runs see the same world iff they act the same."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch

from testbed.core.types import IMAGE_SIZE, ArmObservation, PushResult
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import get_algorithm
from testbed.fleet.loop import FleetLoop
from testbed.learning import Learner
from testbed.learning.learning_config import LearningConfig
from testbed.records.steps import RunWriter

ARMS = [f"h{i}/{a}" for i in range(3) for a in ("left", "right")]


class _World:
    """Each arm's picture: noise seeded by (arm, number of pushes so far, last face)."""

    def __init__(self) -> None:
        self.robot_names = list(ARMS)
        self.state = {r: (0, 0) for r in ARMS}
        self.violating = {r: False for r in ARMS}

    def observe(self) -> dict[str, ArmObservation]:
        out = {}
        for k, r in enumerate(ARMS):
            n, face = self.state[r]
            rng = np.random.default_rng([k, n, face])
            img = rng.integers(0, 256, (IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
            out[r] = ArmObservation(r, img, self.violating[r], (0.5, 0.5), (n + k) % 4)
        return out

    def execute(self, pushes: Mapping[str, int], resets: Sequence[str]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k, r in enumerate(ARMS):
            if r in resets:
                self.violating[r] = False
            if r not in pushes:
                out[r] = PushResult(r, None, False, False)
                continue
            n, _ = self.state[r]
            self.state[r] = (n + 1, int(pushes[r]))
            roll = (n * 7 + k * 3 + int(pushes[r])) % 11
            self.violating[r] = roll == 0
            out[r] = PushResult(r, int(pushes[r]), roll in (3, 5), roll == 0)
        return out


def _run(tmp: Path, overlap: bool, steps: int = 8) -> tuple[list[dict[str, Any]], Learner]:
    cfg = LearningConfig(ensemble_size=2, batch_size=8, augmentation_factor=2)
    learner = Learner(cfg, seed=0, num_threads=1)
    rng = np.random.default_rng(0)
    imgs = rng.integers(0, 256, (16, IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
    learner.add_human(imgs, rng.integers(0, 4, 16))
    learner.add_transitions(imgs[:8], rng.integers(0, 4, 8), imgs[8:],
                            np.arange(8) % 3 == 0, np.arange(8) % 4 == 1)
    algorithm = get_algorithm("cur", AlgorithmConfig(t_I=0, u_hat=0.0, t_T=2, t_R=2),
                              len(ARMS), 2, 0)
    tmp.mkdir()
    with RunWriter(tmp) as writer:
        loop = FleetLoop(hosts=_World(), humans=ScriptedHumans(), learner=learner,
                         algorithm=algorithm, writer=writer, steps=steps, num_humans=2,
                         t_T=2, t_R=2, overlap_act=overlap)
        assert (loop._actor is not None) == overlap
        try:
            for t in range(steps):
                loop.step(t)
        finally:
            loop.close()
    rows = [json.loads(line) for line in (tmp / "steps.jsonl").read_text().splitlines()]
    for row in rows:
        row.pop("wall_time"), row.pop("duration_s")
    return rows, learner


def test_training_beside_act_records_what_the_serial_order_records(tmp_path: Path) -> None:
    serial, a = _run(tmp_path / "serial", overlap=False)
    overlap, b = _run(tmp_path / "overlap", overlap=True)
    assert serial == overlap
    modes = {r["mode"] for row in serial for r in row["robots"]}
    assert {"autonomous", "teleop"} <= modes  # humans labelled: the policy's data grew
    assert a.policy_updates == b.policy_updates == 8
    for x, y in zip(a.policy.state_dict().values(), b.policy.state_dict().values(),
                    strict=True):
        assert torch.equal(x, y)


def test_acting_copy_follows_the_learner_and_shares_no_weights() -> None:
    learner = Learner(LearningConfig(ensemble_size=2, batch_size=8), seed=1, num_threads=1)
    actor = learner.acting_copy()
    imgs = np.random.default_rng(1).integers(0, 256, (5, IMAGE_SIZE, IMAGE_SIZE, 3),
                                             dtype=np.uint8)
    before = learner.act(imgs)
    for name, got in asdict(actor.act(imgs)).items():
        np.testing.assert_array_equal(got, getattr(before, name), err_msg=name)
    with torch.no_grad():
        for net in (learner.policy, learner.safety.net, learner.goal.net):
            for p in net.parameters():
                p.add_(0.05)
    stale = actor.act(imgs)  # not synced yet: the old weights
    for name in ("probs", "risk", "goal_risk"):
        np.testing.assert_array_equal(getattr(stale, name), getattr(before, name))
    actor.sync()
    now = learner.act(imgs)
    for name, got in asdict(actor.act(imgs)).items():
        np.testing.assert_array_equal(got, getattr(now, name), err_msg=name)
    assert not np.array_equal(now.risk, before.risk)
    learner.set_parts(read=())  # the parts follow the learner at the next sync
    actor.sync()
    assert not actor.act(imgs).risk.any() and not actor.act(imgs).goal_risk.any()
    # and nothing is shared: training the learner leaves the actor's weights alone
    ids = {id(p) for net in (learner.policy, learner.safety.net, learner.goal.net)
           for p in net.parameters()}
    assert not ids & {id(p) for p in actor._policy.parameters()}
