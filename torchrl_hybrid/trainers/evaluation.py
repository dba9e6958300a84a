"""Evaluation helpers: greedy returns and inverse-model accuracy."""
from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_hybrid.data.expert import EXPERT_ACTION_KEY
from torchrl_hybrid.modules.inverse_dynamics import InverseDynamicsModel

__all__ = ["evaluate_policy", "inverse_model_accuracy"]


@torch.no_grad()
def evaluate_policy(env: EnvBase, policy, max_steps: int, deterministic: bool = True) -> torch.Tensor:
    """Undiscounted return of the first episode of every env in the batch.

    Runs ``max_steps`` steps (set it to the episode cap so every first episode
    ends) with the greedy action (mode of the policy's distribution) by default.
    Returns a ``[num_envs]`` tensor of returns. A policy on another device than
    the env gets its inputs moved there and its outputs moved back.
    """
    etype = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    device = _device_of(policy)
    if device is not None and env.device is not None and device != env.device:
        policy = _on_device(policy, device, env.device)
    with set_exploration_type(etype):
        td = env.rollout(max_steps, policy, break_when_any_done=False, auto_reset=True)
    reward = td.get(("next", "reward")).squeeze(-1)
    done = td.get(("next", "done")).squeeze(-1)
    # steps up to and including the first done of each env
    before_first_done = (done.long().cumsum(-1) - done.long()) == 0
    if not done.any(-1).all():
        raise RuntimeError(
            f"some evaluation episodes did not end within {max_steps} steps; raise max_steps to the episode cap"
        )
    return (reward * before_first_done).sum(-1)


@torch.no_grad()
def inverse_model_accuracy(inverse_model: InverseDynamicsModel, demos: TensorDictBase) -> float:
    """Fraction of expert pairs whose inferred action equals the true expert action."""
    if EXPERT_ACTION_KEY not in demos.keys():
        raise KeyError(f"the demos carry no {EXPERT_ACTION_KEY!r}: accuracy cannot be measured")
    device = _device_of(inverse_model) or demos.device or torch.device("cpu")
    pred = inverse_model.infer(demos["observation"].to(device), demos["next", "observation"].to(device))
    return float((pred == demos[EXPERT_ACTION_KEY].to(device)).float().mean())


def _device_of(module) -> torch.device | None:
    p = next(iter(module.parameters()), None) if hasattr(module, "parameters") else None
    return None if p is None else p.device


def _on_device(policy, device, env_device):
    def run(td: TensorDictBase) -> TensorDictBase:
        return policy(td.to(device)).to(env_device)
    return run
