"""State encoders e_s: what the paper feeds to W_s (a one-hot vector for Taxi,
a CNN's output for Atari). Every encoder exposes ``out_features``."""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["OneHotEncoder"]


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
