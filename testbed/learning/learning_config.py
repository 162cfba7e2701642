"""Learning's config: ``[learning]``, the ensemble's and the critics' sizes and steps.

Why here: the learner reads it (``testbed/learning/``), so its schema lives in its room.
It imports no torch: a config is loaded, and its errors said, before anything heavy is
(``testbed/learning/__init__.py`` imports torch only when a learner is asked for).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from testbed.core.config import StrictModel
from testbed.core.types import DEFAULT_PRE_STEPS

__all__ = ["ClassWeights", "LearningConfig"]


def _weight(default: float, what: str) -> float:
    return Field(default, ge=0.0, le=100.0, allow_inf_nan=False, description=what)  # type: ignore[no-any-return]


class ClassWeights(StrictModel):
    """``[learning.class_weights]``: how much each class of sample counts when
    ``weighting = "intervention"`` (a member draws its minibatch in proportion to its
    bootstrap weight times this). 0 leaves the class out. The defaults and how they were
    chosen: docs/notes/learning.md, "Learning by class"."""

    demo: float = _weight(1.0, "an offline demonstration")
    teleop: float = _weight(2.0, "a human's teleop push (a correction)")
    robot: float = _weight(1.0, "the policy's push in an episode that succeeded")
    pre_intervention: float = _weight(
        0.5, "the policy's push among its last k before a human took the arm")
    robot_failed: float = _weight(
        0.0, "the policy's push in an episode that did not succeed (violation, goal change)")


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

    weighting: Literal["uniform", "intervention"] = Field(
        "uniform", description="uniform: the policy learns from demonstrations and human "
        "labels alike (Fleet-DAgger); intervention: also from the robot's own pushes, each "
        "sample weighted by its class (class_weights; docs/notes/learning.md)")
    pre_intervention_steps: int = Field(
        DEFAULT_PRE_STEPS, ge=0, le=1000, description="k: the robot's last k steps on an arm "
        "before a human took it are pre-intervention (testbed/records/frame_classes.py)")
    class_weights: ClassWeights = Field(default_factory=ClassWeights)

    @property
    def critic_steps(self) -> int:
        """The critics' offline gradient steps (``critic_pretrain_steps`` if set)."""
        return self.pretrain_steps if self.critic_pretrain_steps is None else (
            self.critic_pretrain_steps)
