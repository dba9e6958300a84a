"""State encoders e_s: what the paper feeds to W_s (a one-hot vector for Taxi,
a CNN's output for Atari). Every encoder exposes ``out_features``."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["MLPEncoder", "OneHotEncoder"]


class OneHotEncoder(nn.Module):
    """Encodes a discrete state as a float one-hot vector ``[*B, n]``.

    Args:
        n: number of states.
        input: ``"index"`` for integer states ``[*B]`` (gymnasium's and
            ``GymEnv(categorical_action_encoding=True)``'s encoding, and ours),
            ``"one_hot"`` for states that are already one-hot ``[*B, n]``.

    Examples:
        >>> OneHotEncoder(4)(torch.tensor([2, 0]))
        tensor([[0., 0., 1., 0.],
                [1., 0., 0., 0.]])
    """

    def __init__(self, n: int, input: str = "index"):
        super().__init__()
        if input not in ("index", "one_hot"):
            raise ValueError(f"input must be 'index' or 'one_hot', got {input!r}")
        self.n = n
        self.input = input
        self.out_features = n

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        if self.input == "one_hot":
            return state.float()
        return F.one_hot(state.long(), self.n).float()


class MLPEncoder(nn.Module):
    """Encodes a vector observation ``[*B, n]`` (CartPole, LunarLander) with an MLP:
    ``num_layers`` layers of ``hidden`` units, each followed by ``tanh`` (the usual
    choice for these control tasks, e.g. Stable-Baselines3's default policy).

    Args:
        in_features: size of the observation vector.
        hidden: width of each layer; also ``out_features``.
        num_layers: number of layers (>= 1).

    Examples:
        >>> MLPEncoder(4, hidden=8)(torch.zeros(3, 4)).shape
        torch.Size([3, 8])
    """

    def __init__(self, in_features: int, hidden: int = 64, num_layers: int = 2):
        super().__init__()
        if num_layers < 1:
            raise ValueError(f"num_layers must be >= 1, got {num_layers}")
        layers: list[nn.Module] = []
        width = in_features
        for _ in range(num_layers):
            layers += [nn.Linear(width, hidden), nn.Tanh()]
            width = hidden
        self.net = nn.Sequential(*layers)
        self.in_features, self.out_features = in_features, hidden

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        if obs.shape[-1] != self.in_features:
            raise ValueError(
                f"MLPEncoder expects observations of size {self.in_features}, got shape {tuple(obs.shape)}"
            )
        return self.net(obs.float())
