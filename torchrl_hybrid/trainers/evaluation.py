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
    Returns a ``[num_envs]`` tensor of returns.
    """
    etype = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
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
    pred = inverse_model.infer(demos["observation"], demos["next", "observation"])
    return float((pred == demos[EXPERT_ACTION_KEY]).float().mean())
