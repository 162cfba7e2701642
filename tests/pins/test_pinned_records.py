"""Exact pins of the fleet loop, the allocator and the records, on any x86-64 CPU.

What: a 20-step C.U.R. twin trial (2 hosts x 2 arms, 2 scripted humans) and a protocol
of 2 trials x (Random, C.U.R., Fleet-TD), counterbalanced (each trial its own order),
Random's budget matched to C.U.R.'s, a quantile u_hat, each final policy and the expert
evaluated (14 runs, 4 arms, 1 human; ``pin_replay.PROTOCOL``) run on the real PyBullet
twin (agents in their own processes), with a ``ReplayLearner`` in place of the learner:
it returns, call by call, what the real learner returned when ``learner_trace.json``
was recorded. Every run's rows (``steps.jsonl``, wall_time and duration_s dropped), the
digest of its data store's frames (wall_time zeroed), run.json's thresholds, matched
budget and protocol order, and the digest of what the loop gave the learner (images,
labels, transitions, train calls) must equal ``pinned_records.json`` exactly.

Why a replay: the learner trains online in float32 and torch, oneDNN and MKL pick their
kernels by CPU, so its outputs differ in the last bits between an AVX2 AMD EPYC and an
AVX-512 Intel Xeon, and an arm's action a few steps later (docs/notes/pins.md); no test
may compare them bit for bit across machines. Given those outputs, the rest is
portable: the twin is PyBullet's software renderer and physics (compiled code with no
dispatch by CPU); OpenCV on this path (colour conversion, masked copies, drawing) is
integer arithmetic; numpy's work on it is comparisons, sorting (stable ``lexsort``,
``argmax``), IEEE-exact +, -, *, /, sqrt, sums and ``np.quantile``, none of which
depends on which SIMD kernel numpy dispatches (its sin, exp, log... do, and are not
used there); the random streams (allocator, Random, the twin, scripted humans) are bit
generators. ``test_the_pins_do_not_depend_on_simd_dispatch`` checks it: the pins hold
with numpy's, OpenCV's, glibc's libm and torch's dispatch cut to their baseline. The
learner's own numbers are pinned with tolerances in ``test_learner_numerics.py``.

On the machine that recorded them, the replay gives exactly the records of the real
learner's runs: recording writes the real runs' pins, and the replay is then checked
against them (both scenarios, every run).

Re-record (only on purpose: a change meant to change what the loop, the allocator, the
humans, the twin or the records do, or the recorded scenarios themselves; never to make
a failure on another machine go away, which would be a bug of the pins)::

    TESTBED_RECORD_DIGESTS=1 .venv/bin/python -m pytest tests/pins/test_pinned_records.py

It runs both scenarios with the real learner (pretraining included), writes
``learner_trace.json`` and ``pinned_records.json``, then replays and compares as usual.
Review the diff of ``pinned_records.json``: it is the change of behaviour.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pin_replay import (
    RECORDS,
    TRACE,
    BindRuns,
    LearnerBook,
    differences,
    dump_json,
    pins_of_run,
    run_protocol_scenario,
    run_trial_scenario,
    use_book,
)

from testbed.core.humans import Humans
from testbed.fleet.allocator import Allocator

ROOT = Path(__file__).resolve().parents[2]
RECORDING = os.environ.get("TESTBED_RECORD_DIGESTS") == "1"
SCENARIOS: dict[str, Callable[[Path, LearnerBook, BindRuns | None], dict[str, Any]]] = {
    "trial": run_trial_scenario, "protocol": run_protocol_scenario}
FOLDERS = {"trial": "runs", "protocol": "proto"}
"""Where each scenario writes its run folders, under its root."""


def _record(root: Path) -> None:
    """Both scenarios with the real learner: its outputs to TRACE, the runs' pins to
    RECORDS (so the replay is checked against the real runs)."""
    traces: dict[str, Any] = {}
    pins: dict[str, Any] = {}
    for name, scenario in SCENARIOS.items():
        book = LearnerBook()
        with pytest.MonkeyPatch.context() as mp:
            use_book(mp, book)
            pins[name] = scenario(root / name, book, None)
        traces[name] = book.traces
    TRACE.write_text(dump_json(traces) + "\n")
    RECORDS.write_text(dump_json(pins) + "\n")


@pytest.fixture(scope="module")
def pinned(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    if RECORDING:
        _record(tmp_path_factory.mktemp("recorded"))
    yield json.loads(RECORDS.read_text())


def _replay(scenario: str, root: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    book = LearnerBook(json.loads(TRACE.read_text())[scenario])
    use_book(monkeypatch, book)
    got = SCENARIOS[scenario](root, book, None)
    # every recorded run got its learner from the trace, and no run another learner
    assert sorted(book.learners) == sorted(book.traces)
    return got


@pytest.mark.slow
@pytest.mark.parametrize("scenario", sorted(SCENARIOS))
def test_the_replayed_learner_gives_the_pinned_records(
        scenario: str, pinned: dict[str, Any], tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    got = _replay(scenario, tmp_path, monkeypatch)
    problems = differences(got, pinned[scenario])
    assert not problems, "\n".join(problems)


class _Differs(Exception):
    """A finished run's rows differ from its pins: the scenario may stop there."""


class _StopAtADifference(BindRuns):
    """``BindRuns`` that, as each run starts, pins the runs finished before it (a
    protocol runs them one after another) and ends the scenario at the first whose rows
    differ from their pins. The rest of the protocol cannot take that difference back,
    so running it would prove nothing more: a planted change's test takes the runs up to
    the first it changes, not all 14."""

    def __init__(self, book: LearnerBook, folder: Path, pinned: dict[str, Any]) -> None:
        super().__init__(book)
        self.folder, self.pinned = folder, pinned
        self.got: dict[str, Any] = {}
        """The pins of every finished run judged so far."""

    def humans(self, name: str) -> Humans | None:
        finished = sorted(p for p in self.folder.iterdir() if p.name not in self.got
                          and p.name != name and (p / "summary.json").exists()
                          ) if self.folder.exists() else []
        for run in finished:
            self.got[run.name] = pins_of_run(run, self.book)
            if run.name in self.pinned and any("first differs" in p for p in differences(
                    {run.name: self.got[run.name]}, {run.name: self.pinned[run.name]})):
                raise _Differs(run.name)
        return super().humans(name)


class _ReversedTies(np.random.Generator):
    """The allocator's tie draws reversed: among equal keys the smaller draw goes first."""

    def random(self, *args: Any, **kwargs: Any) -> Any:
        return 1.0 - super().random(*args, **kwargs)


def _plant(change: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Change the allocator behind the pins' back (the config and the pins unchanged)."""
    real_init = Allocator.__init__

    def init(self: Allocator, *args: Any, **kwargs: Any) -> None:
        real_init(self, *args, **kwargs)
        if change == "t_T off by one":
            self.min_teleop_steps += 1  # type: ignore[misc]
        elif change == "ties reversed":
            self._rng = _ReversedTies(self._rng.bit_generator)
        else:
            raise ValueError(change)

    monkeypatch.setattr(Allocator, "__init__", init)


@pytest.mark.slow
@pytest.mark.parametrize(("change", "scenario"), [("t_T off by one", "trial"),
                                                  ("ties reversed", "protocol")])
def test_a_planted_change_of_the_allocator_is_reported(
        change: str, scenario: str, pinned: dict[str, Any], tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The pins are not blind: the allocator's t_T one step longer (the trial's
    teleops), or its ties broken the other way (Fleet-TD's keys tie among violating
    arms: (0, 1)), changes the records, and the comparison says at which step."""
    _plant(change, monkeypatch)
    book = LearnerBook(json.loads(TRACE.read_text())[scenario])
    use_book(monkeypatch, book)
    stop = _StopAtADifference(book, tmp_path / FOLDERS[scenario], pinned[scenario])
    try:
        got = SCENARIOS[scenario](tmp_path, book, stop)
    except _Differs:
        got = stop.got  # the runs up to the first that differs
    problems = differences(got, pinned[scenario])
    assert any("first differs" in p for p in problems), problems


def baseline_dispatch() -> dict[str, str]:
    """The environment that cuts every SIMD dispatch this CPU offers on the pinned path
    back to the library's baseline: numpy's dispatched ufunc loops (its ``X86_V3``,
    ``X86_V4`` ... targets: AVX2, AVX-512, SVML), OpenCV's (``*`` in its CPU line),
    glibc's libm variants (AVX, FMA, AVX2, AVX-512) and torch's kernels (not on the
    path: the learner is replayed; cut too, so that a real learner would show)."""
    import cv2
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

    opencv = [w.strip("*") for w in cv2.getCPUFeaturesLine().split()
              if w.startswith("*") and not w.endswith("?")]
    return {
        "NPY_DISABLE_CPU_FEATURES": " ".join(
            f for f in __cpu_dispatch__ if __cpu_features__.get(f)),
        "OPENCV_CPU_DISABLE": ",".join(opencv),
        "GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX,-AVX2,-FMA,-FMA4,-AVX512F,-AVX512VL,"
                          "-AVX512DQ,-AVX512BW,-AVX512CD",
        "ATEN_CPU_CAPABILITY": "default",
        "ONEDNN_MAX_CPU_ISA": "SSE41",
    }


@pytest.mark.slow
def test_the_pins_do_not_depend_on_simd_dispatch(pinned: dict[str, Any],
                                                  tmp_path: Path) -> None:
    """The replayed scenarios again, in a process (and agents) whose numpy, OpenCV,
    libm and torch run their baseline code only: as on an x86-64 CPU without AVX.
    Where that changes a float on the pinned path (numpy's float32 sin, exp, log or
    tanh, float64 exp or power; libm's sin, atan2, exp: they differ in a measurable
    share of values), the pins would depend on the CPU, and this test says so."""
    env = {k: v for k, v in os.environ.items() if k != "TESTBED_RECORD_DIGESTS"}
    env.update(baseline_dispatch())
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", str(Path(__file__)), "-q", "-p", "no:cacheprovider",
         "-k", "the_replayed_learner_gives", f"--basetemp={tmp_path / 'inner'}"],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert "2 passed" in proc.stdout, proc.stdout[-2000:]
