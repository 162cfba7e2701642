"""The expert row: the loop's actions are the twin's expert pushes of the last
observation, arm by arm, in the fleet's order (the protocol test runs it on real twin
hosts; here the hosts are a stand-in whose answers the test knows)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from testbed.core.types import IMAGE_SIZE, ArmObservation, Fault
from testbed.experiments.expert import ExpertHosts, ExpertPolicy


class _Hosts:
    def __init__(self) -> None:
        self.robot_names = ["a/l", "a/r", "b/l"]
        self.expert: list[int | None] = [2, 3, None]
        self.started = False

    def observe(self) -> dict[str, ArmObservation | Fault]:
        img = np.zeros((IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8)
        out: dict[str, ArmObservation | Fault] = {
            r: ArmObservation(r, img, e is None, (0.0, 0.0), e)
            for r, e in zip(self.robot_names[:2], self.expert[:2], strict=True)}
        out["b/l"] = Fault("b/l", "link down")
        return out

    def execute(self, pushes: Mapping[str, int], resets: Sequence[str]) -> dict[str, object]:
        return {}

    def start(self) -> None:
        self.started = True


def test_the_expert_pushes_what_the_twin_says_for_each_arm() -> None:
    inner = _Hosts()
    hosts = ExpertHosts(inner)
    policy = ExpertPolicy(hosts)
    hosts.start()  # passed through
    assert inner.started
    images = np.zeros((3, IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8)
    hosts.observe()
    out = policy.act(images)
    assert out.actions.tolist() == [2, 3, 0]  # a faulted arm: any face (it does not push)
    assert out.probs[0].tolist() == [0.0, 0.0, 1.0, 0.0]
    assert not out.uncertainty.any() and not out.risk.any()
    inner.expert = [1, 0, None]
    hosts.observe()
    assert policy.act(images).actions.tolist() == [1, 0, 0]
    assert policy.train_step() == {}
