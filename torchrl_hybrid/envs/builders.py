"""Environment builders used by the recipes, tests and notebooks."""
from __future__ import annotations

import gymnasium as gym
from torchrl.envs import EnvBase, GymEnv, RewardSum, SerialEnv, TransformedEnv

from torchrl_hybrid.envs.tabular import TabularEnv, TabularModel

__all__ = ["BACKENDS", "make_toy_text_env"]

BACKENDS = ("auto", "tabular", "gym")


def make_toy_text_env(
    env_id: str = "Taxi-v4",
    num_envs: int = 16,
    *,
    backend: str = "auto",
    max_episode_steps: int | None = 50,
    seed: int | None = None,
) -> EnvBase:
    """A batch of ``num_envs`` envs with integer (state index) observations and actions.

    Episode returns are tracked under ``episode_reward`` (TorchRL's ``RewardSum``).

    Args:
        env_id: a gymnasium id.
        num_envs: number of parallel environments (batch size ``[num_envs]``).
        backend: ``"tabular"`` steps an exact tensor copy of the env built from its
            transition table ``P`` (fast); ``"gym"`` steps the gymnasium env itself
            through TorchRL's ``GymEnv`` in a ``SerialEnv`` (works for any env);
            ``"auto"`` picks ``"tabular"`` when the env has ``P``.
        max_episode_steps: episode cap (gymnasium's TimeLimit); ``None`` keeps the
            env's registered default.
        seed: environment seed.
    """
    if backend not in BACKENDS:
        raise ValueError(f"Unknown env backend {backend!r}; choose one of {BACKENDS}.")
    if num_envs < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}.")
    if backend == "auto":
        backend = "tabular" if hasattr(gym.make(env_id).unwrapped, "P") else "gym"
    if backend == "tabular":
        if max_episode_steps is None:
            max_episode_steps = gym.spec(env_id).max_episode_steps
        env = TabularEnv(
            TabularModel.from_gym(env_id),
            batch_size=(num_envs,),
            max_episode_steps=max_episode_steps,
            seed=seed,
        )
    else:
        kwargs = {} if max_episode_steps is None else {"max_episode_steps": max_episode_steps}

        def make_one():
            return GymEnv(env_id, categorical_action_encoding=True, **kwargs)

        env = SerialEnv(num_envs, make_one)
        if seed is not None:
            env.set_seed(seed)
    return TransformedEnv(env, RewardSum())
