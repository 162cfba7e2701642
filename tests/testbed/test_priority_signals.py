"""A learned priority signal reaches the priority functions by its name: the checklist
"A new priority signal" of docs/ARCHITECTURE.md, as tests.

Why: a signal is computed by the learner (a ``PolicyOutput`` field), carried by the
fleet loop into ``PrioritySignals`` and read by the priority functions that declare it
(``reads``). The loop passes every name of ``LEARNED_SIGNALS`` from the learner's output,
so a new signal is three declarations and no change to the loop; these tests fail when
one of them is skipped, or when the loop stops carrying a signal it was given.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
from loop_fakes import CalmHosts, QuietLearner, RecordingPriority

from testbed.core.types import IMAGE_SIZE
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import ALGORITHMS, get_algorithm
from testbed.fleet.loop import FleetLoop
from testbed.fleet.priorities import CRITIC_OF_SIGNAL, LEARNED_SIGNALS, PrioritySignals
from testbed.learning.api import PolicyOutput
from testbed.records.steps import RunWriter

ARMS = ["h/a", "h/b", "h/c"]
ARMS_SIGNALS = {"t", "violating", "faulted", "available", "waited"}
"""``PrioritySignals`` fields that come from the arms, the humans and the allocator (how
long each arm has waited), not the learner."""
MATRICES = {"features"}
"""Learned, (N, D) per arm: carried beside the signals, not a signal."""


class _Learner(QuietLearner):
    """Every learned signal a value of its own: signal k of arm i is (k + 1) + i / 10."""

    def act(self, images: np.ndarray) -> Any:
        n = len(images)
        values = {name: (k + 1) + np.arange(n) / 10
                  for k, name in enumerate(sorted(LEARNED_SIGNALS))}
        return SimpleNamespace(actions=np.full(n, 2), **values,
                               features=np.arange(n * 3, dtype=float).reshape(n, 3))


def test_every_learned_signal_is_declared_where_it_is_computed_and_carried() -> None:
    output = {f.name for f in dataclasses.fields(PolicyOutput)}
    carried = {f.name for f in dataclasses.fields(PrioritySignals)} - ARMS_SIGNALS - MATRICES
    assert output >= LEARNED_SIGNALS | MATRICES, (LEARNED_SIGNALS | MATRICES) - output
    assert carried == LEARNED_SIGNALS, carried ^ LEARNED_SIGNALS
    assert set(CRITIC_OF_SIGNAL) <= LEARNED_SIGNALS
    for name, spec in ALGORITHMS.items():  # what each algorithm reads is a known signal
        assert spec.reads <= LEARNED_SIGNALS, (name, spec.reads)


def test_the_loop_hands_every_learned_signal_to_the_priority_function(tmp_path: Path) -> None:
    algorithm = get_algorithm("cur", AlgorithmConfig(t_I=0, u_hat=0.0, t_T=1, t_R=1),
                              len(ARMS), 1, seed=0)
    recording = RecordingPriority(algorithm.priority)
    algorithm.priority = recording
    with RunWriter(tmp_path) as writer:
        loop = FleetLoop(hosts=CalmHosts(ARMS), humans=ScriptedHumans(), learner=_Learner(),
                         algorithm=algorithm, writer=writer, steps=2, num_humans=1,
                         t_T=1, t_R=1)
        try:
            for t in range(2):
                loop.step(t)
        finally:
            loop.close()
    assert len(recording.seen) == 2
    want = _Learner().act(np.zeros((len(ARMS), IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8))
    for signals in recording.seen:
        for name in LEARNED_SIGNALS:
            np.testing.assert_array_equal(signals.signal(name, len(ARMS)), getattr(want, name),
                                          err_msg=name)
        np.testing.assert_array_equal(signals.features_array(len(ARMS)), want.features)
