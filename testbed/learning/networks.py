"""The lab's image network, shared by the policy members and the critics.

Why one builder: the policy ensemble and both critics see the same 64x64 images, and the
paper uses one network (conv 24-36-48 5x5 stride 2, conv 64-64 3x3, ELU, FC 256-256-4).
Input normalisation lives inside the model (``ImageInput``), so every caller passes the
raw uint8 NHWC images it has and no caller can forget or double the scaling.

Shapes for a 64x64 input: 64 -> 30 -> 13 -> 5 (5x5 stride 2) -> 3 -> 1 (3x3), so the
trunk yields 64 features per image.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from testbed.core.types import NUM_ACTIONS

TRUNK_FEATURES = 64
HIDDEN = 256


class ImageInput(nn.Module):
    """uint8 (B, H, W, 3) -> float (B, 3, H, W) roughly in [-1, 1].

    The permute is a view: the conv input stays channels-last in memory, which oneDNN
    runs faster on CPU (measured in benchmarks/bench_training.py).
    """

    def forward(self, images: Tensor) -> Tensor:
        x = images.permute(0, 3, 1, 2).float()  # a new tensor: safe to scale in place
        return x.mul_(1.0 / 127.5).sub_(1.0)


def conv_trunk() -> nn.Sequential:
    """uint8 images -> (B, 64) features."""
    return nn.Sequential(
        ImageInput(),
        nn.Conv2d(3, 24, 5, stride=2),
        nn.ELU(),
        nn.Conv2d(24, 36, 5, stride=2),
        nn.ELU(),
        nn.Conv2d(36, 48, 5, stride=2),
        nn.ELU(),
        nn.Conv2d(48, 64, 3),
        nn.ELU(),
        nn.Conv2d(64, 64, 3),
        nn.ELU(),
        nn.Flatten(),
    )


def mlp_head(out_features: int = NUM_ACTIONS) -> nn.Sequential:
    """(B, 64) features -> (B, out_features): FC 256-256-out."""
    return nn.Sequential(
        nn.Linear(TRUNK_FEATURES, HIDDEN),
        nn.ELU(),
        nn.Linear(HIDDEN, HIDDEN),
        nn.ELU(),
        nn.Linear(HIDDEN, out_features),
    )


def lab_network(out_features: int = NUM_ACTIONS) -> nn.Sequential:
    """One policy member: uint8 images -> (B, out_features) logits."""
    return nn.Sequential(conv_trunk(), mlp_head(out_features))


class TwinQNetwork(nn.Module):
    """Q(s, .) for every action from two heads on one conv trunk: (B, 2, 4) logits.

    Twin heads rather than two whole networks: the heads give the twin estimate that the
    pessimistic target needs, and sharing the trunk halves the critic's share of a
    training step on a 2-core CPU (the conv trunk is most of the cost).
    """

    def __init__(self, num_actions: int = NUM_ACTIONS) -> None:
        super().__init__()
        self.trunk = conv_trunk()
        self.heads = nn.ModuleList([mlp_head(num_actions), mlp_head(num_actions)])

    def forward(self, images: Tensor) -> Tensor:
        features = self.trunk(images)
        return torch.stack([head(features) for head in self.heads], dim=1)

