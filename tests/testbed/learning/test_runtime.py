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
from testbed.learning.runtime import compiler_deterministic
compiler_deterministic()  # what compile_act runs before torch.compile
import torch._inductor.config as inductor
print(inductor.deterministic)
inductor.deterministic = False
configure_torch(1)  # imported already: set as torch's own call sets it
print(inductor.deterministic)
"""


def test_deterministic_warn_only_without_importing_the_compiler() -> None:
    """Deterministic algorithms on, warn-only, as ``torch.use_deterministic_algorithms``
    sets them, but torch's compiler is not imported for it (1.5 CPU-s a process); before
    ``torch.compile`` (``compile_act``) and where something imported the compiler
    already, its flag is set too, as torch's call would."""
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True,
                         check=True, timeout=120).stdout.split("\n")
    assert out[0] == "True True 1 False", out
    assert out[1:3] == ["True", "True"], out
