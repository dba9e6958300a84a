"""The paper's Atari networks: a shared CNN encoder, linear actor and critic heads."""
from __future__ import annotations

import torch
from torch import nn
from torchrl.modules import ValueOperator

from torchrl_hybrid.modules.actor_critic import make_policy

__all__ = ["AtariEncoder", "make_atari_actor_critic"]


class AtariEncoder(nn.Module):
    """conv 32 8x8/4, conv 64 4x4/2, conv 32 3x3/1, fc 512, ReLU after each.

    Note the third convolution has 32 filters (the paper's text), not the usual 64.
    Takes uint8 frame stacks ``[*B, stack, 84, 84]`` (any leading dims) and scales
    them to [0, 1]. ``out_features`` (512) is what the inverse model's ``W_s`` reads.

    Examples:
        >>> AtariEncoder()(torch.zeros(2, 3, 4, 84, 84, dtype=torch.uint8)).shape
        torch.Size([2, 3, 512])
    """

    def __init__(self, stack: int = 4, size: int = 84, out_features: int = 512):
        super().__init__()
        self.convs = nn.Sequential(
            nn.Conv2d(stack, 32, 8, stride=4), nn.ReLU(),
            nn.Conv2d(32, 64, 4, stride=2), nn.ReLU(),
            nn.Conv2d(64, 32, 3, stride=1), nn.ReLU(),
            nn.Flatten(),
        )
        with torch.no_grad():
            n = self.convs(torch.zeros(1, stack, size, size)).shape[-1]
        self.fc = nn.Sequential(nn.Linear(n, out_features), nn.ReLU())
        self.out_features = out_features
        self.in_shape = (stack, size, size)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        lead = frames.shape[: -3]
        if tuple(frames.shape[-3:]) != self.in_shape:
            raise ValueError(f"expected frame stacks of shape {self.in_shape}, got {tuple(frames.shape[-3:])}")
        x = frames.reshape(-1, *self.in_shape).float().div_(255.0)
        return self.fc(self.convs(x)).reshape(*lead, self.out_features)


def make_atari_actor_critic(n_actions: int, encoder: AtariEncoder | None = None):
    """Actor and critic sharing one :class:`AtariEncoder` (returned too, so that the
    inverse model can share it as in the paper)."""
    encoder = encoder if encoder is not None else AtariEncoder()
    actor = make_policy(nn.Sequential(encoder, nn.Linear(encoder.out_features, n_actions)))
    critic = ValueOperator(nn.Sequential(encoder, nn.Linear(encoder.out_features, 1)), in_keys=["observation"])
    return actor, critic, encoder
