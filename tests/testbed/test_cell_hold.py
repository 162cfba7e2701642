"""The hard-reset policy of a shared cell: while a person resets one of a YuMi's arms, the
other arm of that table does not move.

``FleetLoop(cells=...)`` (``testbed.experiments.build.shared_cells``: a YuMi host's arms
share its cell, a twin's share nothing) holds the pushes of every robot whose cell has an
arm in reset mode, from the step the reset is assigned to the step it is confirmed. The
hosts here record what they were sent, so the test sees that the held push never went
out; the records show it as ``refused`` with the reason and the face that was chosen.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
from loop_fakes import QuietLearner

from testbed.core.types import IMAGE_SIZE, ArmObservation, PushResult
from testbed.experiments.build import shared_cells
from testbed.experiments.fleet_config import parse_config
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import get_algorithm
from testbed.fleet.loop import FleetLoop
from testbed.records.steps import RunWriter, read_steps

ARMS = ["yumi-a/left", "yumi-a/right", "cell0/left"]
CELLS = {"yumi-a/left": "yumi-a", "yumi-a/right": "yumi-a"}


class _Hosts:
    """yumi-a/left violates from step 1 until its reset is done; the others never do."""

    def __init__(self) -> None:
        self.robot_names = list(ARMS)
        self.sent: list[tuple[dict[str, int], list[str]]] = []
        self.left_out = False

    def observe(self) -> dict[str, ArmObservation]:
        img = np.zeros((IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8)
        return {r: ArmObservation(r, img, r == ARMS[0] and self.left_out, (0.5, 0.5), 1)
                for r in ARMS}

    def execute(self, pushes: Mapping[str, int], resets: Sequence[str]) -> dict[str, Any]:
        self.sent.append((dict(pushes), list(resets)))
        out = {r: PushResult(r, pushes.get(r), False, r == ARMS[0] and not self.left_out
                             and len(self.sent) == 1) for r in ARMS}
        if len(self.sent) == 1:
            self.left_out = True  # the first push knocks the cube out
        if ARMS[0] in resets:
            self.left_out = False
        return out


class _Learner(QuietLearner):
    def act(self, images: np.ndarray) -> Any:
        n = len(images)
        z = np.zeros(n)
        return SimpleNamespace(actions=np.full(n, 2), uncertainty=z, risk=z, goal_risk=z,
                               novelty=z)


def _run(tmp: Path, cells: Mapping[str, str]) -> tuple[_Hosts, list[dict[str, Any]]]:
    algorithm = get_algorithm("cur", AlgorithmConfig(t_I=0, u_hat=1.0, t_T=1, t_R=3),
                              len(ARMS), 1, seed=0)
    hosts = _Hosts()
    tmp.mkdir()
    with RunWriter(tmp) as writer:
        loop = FleetLoop(hosts=hosts, humans=ScriptedHumans(), learner=_Learner(),
                         algorithm=algorithm, writer=writer, steps=7, num_humans=1,
                         t_T=1, t_R=3, cells=cells)
        try:
            for t in range(7):
                loop.step(t)
        finally:
            loop.close()
    return hosts, read_steps(tmp)


def test_a_reset_holds_the_other_arm_of_its_cell_and_nothing_else(tmp_path: Path) -> None:
    hosts, rows = _run(tmp_path / "held", CELLS)
    modes = [{r["robot"]: r["mode"] for r in row["robots"]} for row in rows]
    reset_steps = [t for t, m in enumerate(modes) if m[ARMS[0]] == "reset"]
    assert reset_steps == [1, 2, 3], modes  # knocked out at 0, seen at 1, t_R = 3 steps
    for t in reset_steps:
        right = next(r for r in rows[t]["robots"] if r["robot"] == ARMS[1])
        assert right["mode"] == "refused" and right["action"] == 2
        assert right["refused"] == ("held: a person is resetting yumi-a/left in the same "
                                    "cell (yumi-a)")
        assert ARMS[1] not in hosts.sent[t][0]  # never sent to the host
        assert hosts.sent[t][0].get(ARMS[2]) == 2  # another cell pushes on
    assert hosts.sent[3][1] == [ARMS[0]]  # the reset is confirmed at its last step ...
    assert modes[4][ARMS[1]] == "autonomous" and hosts.sent[4][0].get(ARMS[1]) == 2  # ... free


def test_without_shared_cells_nothing_is_held(tmp_path: Path) -> None:
    hosts, rows = _run(tmp_path / "free", {})
    assert all(r["mode"] != "refused" for row in rows for r in row["robots"])
    assert all(ARMS[1] in sent for sent, _ in hosts.sent)


def test_shared_cells_are_the_yumi_hosts_arms() -> None:
    cfg = parse_config(tomllib.loads(
        '[[hosts]]\nname = "cell0"\n'
        '[[hosts]]\nname = "yumi-a"\nbackend = "yumi"\ncamera = "0"\n'
        'controller_url = "http://192.0.2.1"\n'
        'arms = [{name = "left", crop = [0, 0, 10, 10], calibration = "l.json"},\n'
        '        {name = "right", crop = [10, 0, 20, 10], calibration = "r.json"}]\n'))
    assert shared_cells(cfg) == CELLS
