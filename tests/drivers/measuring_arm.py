"""``MeasuringBackend``: canned arms whose push the host times (a reading, ``push_s``),
and, run as a script, the REAL agent serving it.

Why: a value only the robot host can measure (the push's duration on its own clock, a
controller's reading) travels to the controller's ``PushResult`` and the arm's
steps.jsonl row by one generic path, ``ArmOutcome.readings`` (docs/ARCHITECTURE.md, "A
new field in every step"). This backend is what a lab's backend does to add one: its
``push`` fills ``readings["push_s"]``, and nothing else changes. The seam is
``slow_arm.py``'s: ``python tests/drivers/measuring_arm.py ARGV`` runs the agent with
this backend, a leading ``-m drivers.agent`` dropped. Environment: ``MEASURING_ARM_S``
(how long a push moves, default 0.02 s), ``MEASURING_ARM_BAD`` (a reading the backend
gets wrong, e.g. ``nan``, on the arm ``left``: a backend's bug).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Mapping, Sequence
from typing import Any

from slow_arm import run_agent

from drivers.backends.base import ArmOutcome, HostBackend
from drivers.backends.twin import CannedTwinBackend

MOVE_S_ENV = "MEASURING_ARM_S"
BAD_ENV = "MEASURING_ARM_BAD"


class MeasuringBackend(CannedTwinBackend):
    """The canned twin's outcomes; each pushed arm's ``readings`` say how long the
    push took on this host (``push_s``, ``time.monotonic()``)."""

    def __init__(self, seed: int, arms: Sequence[str] = ("left", "right"),
                 mirror: Sequence[bool] = (False, True), *, move_s: float = 0.02,
                 bad: str | None = None) -> None:
        super().__init__(seed, arms, mirror)
        self.move_s = move_s
        self.bad = bad

    def push(self, faces: Mapping[str, int]) -> dict[str, ArmOutcome]:
        started = time.monotonic()
        out = super().push(faces)
        time.sleep(self.move_s)  # the arms move
        took = time.monotonic() - started
        return {arm: ArmOutcome(o.success, o.violation, o.refused, o.error,
                                {"push_s": float(self.bad) if self.bad and arm == "left"
                                 else took})
                for arm, o in out.items()}


def _factory(args: argparse.Namespace, kwargs: dict[str, Any]) -> HostBackend:
    return MeasuringBackend(args.seed, kwargs["arms"], kwargs["mirror"],
                            move_s=float(os.environ.get(MOVE_S_ENV, "0.02")),
                            bad=os.environ.get(BAD_ENV))


def main(argv: Sequence[str]) -> int:
    return run_agent(argv, _factory)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
