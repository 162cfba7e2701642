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
    gamma_value: float = Field(
        0.8, ge=0, le=1, description="the value critic's discount (the advantage's, "
        "weighting = \"advantage\"): the goal critic's targets on a shorter horizon, "
        "so a push that brings the goal nearer counts (docs/notes/learning.md, 'The value "
        "of every push')")
    device: Literal["auto", "cpu", "cuda"] = "auto"
    compile_act: bool = Field(
        False, description="run the fleet loop's forward pass through torch.compile: "
        "1.65x faster at 100 arms on 2 CPU cores, ~20 s to compile, needs a C compiler "
        "(falls back to eager with a warning); not worth it for a few arms")

    weighting: Literal["uniform", "intervention", "advantage"] = Field(
        "uniform", description="uniform: the policy learns from demonstrations and human "
        "labels alike (Fleet-DAgger); intervention: also from the robot's own pushes, each "
        "sample weighted by its class (class_weights; docs/notes/learning.md); advantage: "
        "from every push, each weighted by exp(A / advantage_temperature), A its advantage "
        "under the value critic, which then trains online (testbed/learning/advantage.py)")
    advantage_temperature: float = Field(
        0.1, gt=0.0, le=10.0, allow_inf_nan=False, description="AWR's temperature: the "
        "smaller, the more a push better than the policy's counts (A lies in [-1, 1])")
    advantage_max_weight: float = Field(
        20.0, ge=1.0, le=1000.0, allow_inf_nan=False,
        description="AWR's clip of a sample's weight exp(A / temperature)")
    conditioning: Literal["none", "advantage"] = Field(
        "none", description="advantage: the policy sees whether each sample's advantage "
        "is above advantage_threshold and acts as if it is (RECAP's way; "
        "testbed/learning/advantage.py); learns from every push, as weighting = advantage")
    advantage_threshold: float = Field(
        0.0, ge=-1.0, le=1.0, allow_inf_nan=False,
        description="conditioning: a sample is POSITIVE where its advantage is above this")
    condition_dropout: float = Field(
        0.3, ge=0.0, le=1.0, allow_inf_nan=False, description="conditioning: the chance "
        "that a drawn sample's indicator is dropped (the policy learns to act without it)")
    advantage_refresh: int = Field(
        100, ge=1, le=100000, description="policy updates between two passes that value "
        "every sample again (a pass costs about two training steps; new samples are "
        "valued every 10 updates)")
    value_every: int = Field(
        3, ge=1, le=1000, description="the value critic trains on every n-th critic "
        "minibatch (its share of a training step; benchmarks/bench_weighting.py)")
    pre_intervention_steps: int = Field(
        DEFAULT_PRE_STEPS, ge=0, le=1000, description="k: the robot's last k steps on an arm "
        "before a human took it are pre-intervention (testbed/records/frame_classes.py)")
    class_weights: ClassWeights = Field(default_factory=ClassWeights)

    @property
    def by_advantage(self) -> bool:
        """Whether the policy learns from every push's advantage (weighting or
        conditioning): the value critic then trains online, the robot's pushes come in."""
        return self.weighting == "advantage" or self.conditioning == "advantage"

    @property
    def critic_steps(self) -> int:
        """The critics' offline gradient steps (``critic_pretrain_steps`` if set)."""
        return self.pretrain_steps if self.critic_pretrain_steps is None else (
            self.critic_pretrain_steps)
