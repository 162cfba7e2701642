"""How the learner sets torch up in a process (``testbed/learning/runtime.py``)."""

from __future__ import annotations

import subprocess
import sys

CHILD = """
import sys
import torch
from testbed.learning.runtime import configure_torch
assert not torch.are_deterministic_algorithms_enabled()
configure_torch(1)
print(torch.are_deterministic_algorithms_enabled(),
      torch.is_deterministic_algorithms_warn_only_enabled(),
      torch.get_num_threads(), "torch._inductor" in sys.modules)
import torch._inductor.config as inductor
configure_torch(1)
print(inductor.deterministic)
"""


def test_deterministic_warn_only_without_importing_the_compiler() -> None:
    """Deterministic algorithms on, warn-only, as ``torch.use_deterministic_algorithms``
    sets them, but torch's compiler is not imported for it (1.5 CPU-s a process); where
    something imported it already, its flag is set too, as torch's call would."""
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True,
                         check=True, timeout=120).stdout.split("\n")
    assert out[0] == "True True 1 False", out
    assert out[1] == "True", out
