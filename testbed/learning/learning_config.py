"""Learning's config: ``[learning]``, the ensemble's and the critics' sizes and steps.

Why here: the learner reads it (``testbed/learning/``), so its schema lives in its room.
It imports no torch: a config is loaded, and its errors said, before anything heavy is
(``testbed/learning/__init__.py`` imports torch only when a learner is asked for).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from testbed.core.config import StrictModel

__all__ = ["LearningConfig"]


class LearningConfig(StrictModel):
    ensemble_size: int = Field(5, ge=1, le=32)
    batch_size: int = Field(256, ge=1, le=65536)
    lr: float = Field(3e-4, gt=0, lt=1)
    augmentation_factor: int = Field(10, ge=1, le=100)
    gradient_steps: int = Field(1, ge=0, le=100, description="per timestep")
    demos: int = Field(375, ge=1, description="offline state-action pairs")
    critic_transitions: int = Field(1000, ge=0, description="BC rollouts for the critics")
    pretrain_steps: int = Field(300, ge=0)
    critic_pretrain_steps: int | None = Field(
        None, ge=0, description="critics' offline steps; None: pretrain_steps. The seed "
        "trains them 3000 steps; the goal critic needs ~600 at batch 64 (docs/notes/learning.md)")
    gamma_safe: float = Field(0.5, ge=0, le=1)
    gamma_goal: float = Field(0.999, ge=0, le=1)
    device: Literal["auto", "cpu", "cuda"] = "auto"
    compile_act: bool = Field(
        False, description="run the fleet loop's forward pass through torch.compile: "
        "1.65x faster at 100 arms on 2 CPU cores, ~20 s to compile, needs a C compiler "
        "(falls back to eager with a warning); not worth it for a few arms")

    @property
    def critic_steps(self) -> int:
        """The critics' offline gradient steps (``critic_pretrain_steps`` if set)."""
        return self.pretrain_steps if self.critic_pretrain_steps is None else (
            self.critic_pretrain_steps)
