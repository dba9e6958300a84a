"""Environment builders used by the recipes, tests and notebooks."""

from __future__ import annotations

import gymnasium as gym
from torchrl.envs import EnvBase, GymEnv, GymWrapper, RewardSum, SerialEnv, TransformedEnv

from torchrl_hybrid.envs.tabular import TabularEnv, TabularModel

__all__ = ["BACKENDS", "make_gym_env", "observation_kind"]

BACKENDS = ("auto", "tabular", "gym", "vector")


def observation_kind(env_id: str, env_kwargs: dict | None = None) -> tuple[str, int, int]:
    """``("discrete", n_states, n_actions)`` for a ``Discrete`` observation space (toy-text
    envs), ``("vector", size, n_actions)`` for a flat ``Box`` one (CartPole, LunarLander);
    any other space, or actions that are not ``Discrete``, is refused with what to use instead."""
    env = gym.make(env_id, **dict(env_kwargs or {}))
    obs, act = env.observation_space, env.action_space
    env.close()
    if not isinstance(act, gym.spaces.Discrete):
        raise ValueError(
            f"{env_id}: actions are {act}; the hybrid agent needs discrete actions (an inverse model "
            "over a finite action set)"
        )
    if isinstance(obs, gym.spaces.Discrete):
        return "discrete", int(obs.n), int(act.n)
    if isinstance(obs, gym.spaces.Box) and len(obs.shape) == 1:
        return "vector", int(obs.shape[0]), int(act.n)
    raise ValueError(
        f"{env_id}: observations are {obs}; this pipeline takes discrete states or flat vectors "
        "(for Atari frames use recipes/atari.py)"
    )


def make_gym_env(
    env_id: str = "Taxi-v4",
    num_envs: int = 16,
    *,
    backend: str = "auto",
    max_episode_steps: int | None = 50,
    seed: int | None = None,
    env_kwargs: dict | None = None,
) -> EnvBase:
    """A batch of ``num_envs`` envs with integer actions, and integer (state index)
    observations for toy-text envs or float vectors for control envs such as CartPole.

    Episode returns are tracked under ``episode_reward`` (TorchRL's ``RewardSum``).

    Args:
        env_id: a gymnasium id.
        num_envs: number of parallel environments (batch size ``[num_envs]``).
        backend: ``"tabular"`` steps an exact tensor copy of the env built from its
            transition table ``P`` (fast); ``"gym"`` steps the gymnasium env itself
            through TorchRL's ``GymEnv`` in a ``SerialEnv`` (works for any env);
            ``"vector"`` steps one gymnasium ``SyncVectorEnv`` (same-step autoreset, so
            ``("next", "observation")`` is the true final state) through TorchRL's
            ``GymWrapper``: one TorchRL step for the whole batch, about twice as fast as
            ``"gym"`` on CartPole; ``"auto"`` picks ``"tabular"`` when the env has ``P``,
            else ``"vector"``.
        max_episode_steps: episode cap (gymnasium's TimeLimit); ``None`` keeps the
            env's registered default.
        seed: environment seed.
        env_kwargs: keyword arguments of ``gym.make`` (e.g. FrozenLake's
            ``map_name="8x8", is_slippery=False``).
    """
    env_kwargs = dict(env_kwargs or {})
    if backend not in BACKENDS:
        raise ValueError(f"Unknown env backend {backend!r}; choose one of {BACKENDS}.")
    if num_envs < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}.")
    if backend == "auto":
        backend = "tabular" if hasattr(gym.make(env_id, **env_kwargs).unwrapped, "P") else "vector"
    if backend == "tabular":
        if max_episode_steps is None:
            max_episode_steps = gym.spec(env_id).max_episode_steps
        env = TabularEnv(
            TabularModel.from_gym(env_id, **env_kwargs),
            batch_size=(num_envs,),
            max_episode_steps=max_episode_steps,
            seed=seed,
        )
    elif backend == "vector":
        kwargs = (
            dict(env_kwargs) if max_episode_steps is None else {**env_kwargs, "max_episode_steps": max_episode_steps}
        )
        venv = gym.vector.SyncVectorEnv(
            [lambda: gym.make(env_id, **kwargs) for _ in range(num_envs)],
            autoreset_mode=gym.vector.AutoresetMode.SAME_STEP,
        )
        env = GymWrapper(venv, categorical_action_encoding=True)
        if seed is not None:
            env.set_seed(seed)
    else:
        kwargs = (
            dict(env_kwargs) if max_episode_steps is None else {**env_kwargs, "max_episode_steps": max_episode_steps}
        )

        def make_one():
            return GymEnv(env_id, categorical_action_encoding=True, **kwargs)

        env = SerialEnv(num_envs, make_one)
        if seed is not None:
            env.set_seed(seed)
    if isinstance(env, TransformedEnv):  # GymWrapper over a vector env comes with its own autoreset transform
        env.append_transform(RewardSum())
        return env
    return TransformedEnv(env, RewardSum())
