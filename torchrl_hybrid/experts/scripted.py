"""Experts that are not RL checkpoints: any callable policy, e.g. a hand-written controller.

``demo.expert=<module>:<function>`` (instead of a ``model.pt``) names a function that maps a
batch of observations ``[n, obs_dim]`` (a float tensor) to ``n`` discrete actions (any
integer array or tensor). :func:`load_callable_expert` wraps it as a TorchRL policy, which the
gymnasium family plays to record the state-only demos
(:func:`~torchrl_hybrid.experts.record_episodes`) and to measure the expert's return, as it
does with a checkpoint. Two such experts ship here, stated as scripted, not learned.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

import torch
from tensordict.nn import TensorDictModule
from torch import nn

__all__ = ["CallablePolicy", "load_callable_expert", "is_callable_spec", "mountain_car_energy", "acrobot_energy"]


def mountain_car_energy(obs: torch.Tensor) -> torch.Tensor:
    """MountainCar-v0, scripted: push in the direction the car moves (2 = right, 0 = left),
    which pumps energy into the swing until the car clears the hill; from rest, push left
    first. Return -127 on average over 32 seeded episodes (-86 to -174; 200 steps is the cap)."""
    velocity = obs[..., 1]
    return torch.where(velocity > 0, 2, torch.where(velocity < 0, 0, 0)).long()


def acrobot_energy(obs: torch.Tensor) -> torch.Tensor:
    """Acrobot-v1, scripted: torque the joint in the direction it already turns (2 = +1,
    0 = -1), an energy-pumping heuristic: return -80 on average over 16 seeded episodes
    (-64 to -109); the opposite sign never swings up (-500)."""
    dtheta2 = obs[..., 5]
    return torch.where(dtheta2 > 0, 2, 0).long()


class CallablePolicy(nn.Module):
    """``fn(observation) -> actions`` as a module (no parameters; runs on the CPU)."""

    def __init__(self, fn: Callable):
        super().__init__()
        self.fn = fn

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        action = self.fn(observation)
        action = torch.as_tensor(action)
        if action.shape != observation.shape[:-1]:
            raise ValueError(
                f"the scripted expert returned actions of shape {tuple(action.shape)} for "
                f"observations of shape {tuple(observation.shape)}; return one action per row"
            )
        return action.long()


def is_callable_spec(spec: str | None) -> bool:
    """Whether ``demo.expert`` names a callable (``module:function``) rather than a file."""
    return bool(spec) and ":" in spec and not spec.endswith(".pt") and "/" not in spec.split(":")[0]


def load_callable_expert(spec: str) -> TensorDictModule:
    """The policy ``module:function`` names, as a TorchRL policy (``observation`` -> ``action``)."""
    module_name, _, name = spec.partition(":")
    try:
        fn = getattr(importlib.import_module(module_name), name)
    except (ImportError, AttributeError) as err:
        raise ValueError(
            f"demo.expert={spec!r}: cannot import {name!r} from {module_name!r} ({err}); give "
            "module:function, e.g. torchrl_hybrid.experts.scripted:mountain_car_energy"
        ) from None
    if not callable(fn):
        raise ValueError(f"demo.expert={spec!r} is not callable")
    return TensorDictModule(CallablePolicy(fn), in_keys=["observation"], out_keys=["action"])
