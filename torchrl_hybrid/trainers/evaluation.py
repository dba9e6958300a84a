"""Evaluation: greedy returns (gymnasium envs), game scores (Atari), inverse-model accuracy."""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type
from tqdm import tqdm

from torchrl_hybrid.data.expert import EXPERT_ACTION_KEY
from torchrl_hybrid.envs.atari import AtariEnv
from torchrl_hybrid.modules.inverse_dynamics import InverseDynamicsModel
from torchrl_hybrid.utils.device import module_device, resolve_device

__all__ = ["evaluate_policy", "evaluate_atari", "inverse_model_accuracy"]


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
    env_device = env.device if env.device is not None else torch.device("cpu")  # a device-less env steps on the CPU
    if device is not None and device != env_device:
        policy = _on_device(policy, device, env_device)
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
def evaluate_atari(
    actor,
    game: str,
    preprocessing: dict,
    *,
    episodes: int = 16,
    num_envs: int = 16,
    seed: int = 0,
    deterministic: bool = False,
    num_threads: int = 2,
    max_steps: int | None = None,
    progress: bool = False,
    device: str | torch.device | None = None,
) -> dict[str, Any]:
    """Plays ``episodes`` whole episodes (all lives) with ``actor`` and returns the
    raw game scores: ``{"mean", "std", "scores", "episodes", "deterministic"}``.
    ``max_steps`` (agent steps per env) stops early; unfinished episodes are not counted.
    The actor runs on ``device`` (default: where its parameters are), the games on the CPU."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    device = module_device(actor) if device is None else resolve_device(device)
    torch.manual_seed(seed)
    env = AtariEnv(
        game,
        num_envs,
        seed=seed,
        num_threads=num_threads,
        noop_max=preprocessing["noop_max"],
        max_episode_frames=preprocessing["max_episode_frames"],
    )
    env.check_policy(actor)
    td = env.reset()
    running = torch.zeros(num_envs)
    scores: list[float] = []
    etype = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    bar = tqdm(total=episodes, desc=f"{game} evaluation", disable=not progress)
    steps = 0
    while len(scores) < episodes and (max_steps is None or steps < max_steps):
        with set_exploration_type(etype):
            td = actor(td.to(device)).to("cpu")
        td, root = env.step_and_maybe_reset(td)
        running += td["next", "score"].reshape(num_envs)
        for i in torch.nonzero(td["next", "done"].reshape(num_envs)).flatten().tolist():
            if len(scores) < episodes:
                scores.append(float(running[i]))
                bar.update(1)
            running[i] = 0.0
        td, steps = root, steps + 1
    bar.close()
    env.close()
    t = torch.tensor(scores)
    return {
        "mean": float(t.mean()) if scores else None,
        "std": float(t.std()) if len(scores) > 1 else None,
        "scores": scores,
        "episodes": len(scores),
        "deterministic": deterministic,
    }


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
