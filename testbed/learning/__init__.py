"""Learning: the policy ensemble, the safety and goal critics, augmentation, replay data.

Its learner imports torch (seconds, hundreds of MB), so nothing on the path of ``import
testbed`` imports it: ``Learner`` and the rest are imported when first asked for (the
fleet loop and the CLI ask when a trial or a pretraining starts), and the room's config
(``learning_config.py``) loads without torch. ``Learner`` is the whole public surface the
rest of the testbed needs; the modules behind it are documented in docs/notes/learning.md.
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

import importlib.util
from typing import TYPE_CHECKING, Any

from testbed.core.extras import needs_operator

if TYPE_CHECKING:
    from testbed.learning.api import EnsembleImpl, PolicyOutput, ProgressFn, Transitions
    from testbed.learning.learner import Learner
    from testbed.learning.runtime import LearningError

__all__ = ["EnsembleImpl", "Learner", "LearningError", "PolicyOutput", "ProgressFn", "Transitions"]

def __getattr__(name: str) -> Any:
    """``Learner`` and the rest, imported (with torch) when first asked for, so that the
    room's config (``learning_config.py``) loads without torch. On a host install (no
    torch, no kornia) asking for any of them says so in one line."""
    if name in __all__:
        for package in ("torch", "kornia"):
            if importlib.util.find_spec(package) is None:
                raise needs_operator("testbed.learning", ModuleNotFoundError(
                    f"No module named {package!r}", name=package))
    if name == "EnsembleImpl":
        from testbed.learning.api import EnsembleImpl as found
    elif name == "PolicyOutput":
        from testbed.learning.api import PolicyOutput as found
    elif name == "ProgressFn":
        from testbed.learning.api import ProgressFn as found
    elif name == "Transitions":
        from testbed.learning.api import Transitions as found
    elif name == "Learner":
        from testbed.learning.learner import Learner as found
    elif name == "LearningError":
        from testbed.learning.runtime import LearningError as found
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return found
