"""Learning: the policy ensemble, the safety and goal critics, augmentation, replay data.

Importing this package imports torch (seconds, hundreds of MB), so nothing on the path of
``import testbed`` imports it: the fleet loop and the CLI import it when a trial or a
pretraining starts. ``Learner`` is the whole public surface the rest of the testbed
needs; the modules behind it are documented in docs/notes/learning.md.
"""

from __future__ import annotations

from testbed.learning.api import EnsembleImpl, PolicyOutput, ProgressFn, Transitions
from testbed.learning.learner import Learner
from testbed.learning.runtime import LearningError

__all__ = ["EnsembleImpl", "Learner", "LearningError", "PolicyOutput", "ProgressFn", "Transitions"]
