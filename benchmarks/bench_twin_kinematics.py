"""The hardware twin's line supervision: one sample of a SingArea Wrist line, one pose's
arm angle, one pose's joint frames.

Why this exists: the YuMi twin judges every line an arm is sent sample by sample (every
5 mm: ``sim_twin/rws/arm_supervision.py``), each sample a damped least-squares descent
(``sim_twin/yumi_ik.py::tip_descend``) whose every iteration asks the arm angle and its
gradient of one pose (``sim_twin/sew_angle.py``) and that pose's joint frames
(``sim_twin/yumi_arms.py``). In a sampled profile of the whole test suite this
supervision was the largest single CPU cost of the YuMi rehearsals, calibrations and
twin tests (docs/notes/tests.md, "Issue 45, item 6"). Printed, each measured in this one
run against its reference (ratio = reference / variant, > 1 is faster):

1. the arm angle and gradient of one pose on plain floats (what the descent calls)
   against the numpy batch path given the same pose twice (the path every pose took
   before); the two agree to 1e-12 (tests/sim_twin/test_sew_angle_paths.py);
2. one pose's joint frames, seven turned offsets at once, against the chain of
   ``base @ rot_z(q) @ offset`` products written out here;
3. one ``tip_descend`` (a line sample 3 mm off, the arm angle turned 5 deg), for scale.

Interleaved repeats, medians.

    .venv/bin/python benchmarks/bench_twin_kinematics.py [--calls 2000] [--repeats 7]
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim_twin.sew_angle import arm_angle_batch
from sim_twin.yumi_arms import _OFFSETS, ArmModel
from sim_twin.yumi_ik import tip_descend

Q = [10.0, -130.0, 30.0, 30.0, 40.0, 30.0, 5.0]


def _chain(model: ArmModel, chain_deg: list[float]) -> np.ndarray:
    """The joint frames as products of 4x4 matrices, one rotation matrix per joint."""
    frames = np.empty((8, 4, 4))
    m = model.base
    for k, q in enumerate(chain_deg):
        frames[k] = m
        rz = np.eye(4)
        c, s = math.cos(math.radians(q)), math.sin(math.radians(q))
        rz[0, 0], rz[0, 1], rz[1, 0], rz[1, 1] = c, -s, s, c
        m = m @ rz @ _OFFSETS[k]
    frames[7] = m
    return frames


def _per_call_us(fn: Callable[[], object], calls: int) -> float:
    t = time.process_time()
    for _ in range(calls):
        fn()
    return (time.process_time() - t) / calls * 1e6


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=7)
    a = ap.parse_args(argv)
    model = ArmModel("left")
    pose = model.pose(Q)
    one, two = pose.frames[None], np.concatenate([pose.frames[None]] * 2)
    assert np.allclose(_chain(model, Q), pose.frames, atol=1e-9)
    tip = pose.flange[:3, 3] + pose.flange[:3, 2] * 184.2 + np.array([3.0, 0.0, 0.0])
    angle = math.degrees(float(arm_angle_batch(one)[0][0])) + 5.0
    cases: dict[str, Callable[[], object]] = {
        "arm angle, one pose": lambda: arm_angle_batch(one),
        "arm angle, batch path": lambda: arm_angle_batch(two),
        "frames, offsets turned at once": lambda: model.pose(Q),
        "frames, chain of products": lambda: _chain(model, Q),
        "tip_descend": lambda: tip_descend(model, tip, 184.2, Q, angle),
    }
    times: dict[str, list[float]] = {k: [] for k in cases}
    for _ in range(a.repeats):
        for name, fn in cases.items():
            calls = a.calls if name != "tip_descend" else max(1, a.calls // 20)
            times[name].append(_per_call_us(fn, calls))
    med = {k: statistics.median(v) for k, v in times.items()}
    for name in cases:
        print(f"{name:32s} {med[name]:9.1f} us per call (CPU)")
    print(f"ratio arm angle: batch path / one pose = "
          f"{med['arm angle, batch path'] / med['arm angle, one pose']:.2f}x")
    print(f"ratio frames: chain of products / offsets turned at once = "
          f"{med['frames, chain of products'] / med['frames, offsets turned at once']:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
