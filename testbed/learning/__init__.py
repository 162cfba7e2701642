"""Learning: the policy ensemble, the safety and goal critics, augmentation, replay data.

Importing this package imports torch (seconds, hundreds of MB), so nothing on the path of
``import testbed`` imports it: the fleet loop and the CLI import it when a trial or a
pretraining starts. ``Learner`` is the whole public surface the rest of the testbed
needs; the modules behind it are documented in docs/notes/learning.md.
"""

from __future__ import annotations

import os

# Before torch (and its OpenMP runtime) loads: idle OpenMP workers sleep instead of
# spinning. Training runs beside the hosts' agents and the controller; with the default
# (spinning) policy, 2 threads on 2 cores with the other core busy made a C.U.R. step
# 2.6x SLOWER than 1 thread (7.7 s vs 2.7 s), with PASSIVE they cost nothing (2.9 s),
# and on a free core they are 1.7x faster (1.45 s). docs/notes/learning.md, issue 13.
# setdefault: a lab that tunes OpenMP itself keeps its setting.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from testbed.core.extras import needs_operator

try:  # torch and kornia: the operator install's (a host install says so in one line)
    from testbed.learning.api import EnsembleImpl, PolicyOutput, ProgressFn, Transitions
    from testbed.learning.learner import Learner
    from testbed.learning.runtime import LearningError
except ImportError as exc:
    raise needs_operator("testbed.learning", exc) from None

__all__ = ["EnsembleImpl", "Learner", "LearningError", "PolicyOutput", "ProgressFn", "Transitions"]
