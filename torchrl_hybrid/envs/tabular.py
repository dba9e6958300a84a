"""An exact, batched tensor version of any gymnasium toy-text env that has ``P``.

Gymnasium's toy-text envs (Taxi, FrozenLake, CliffWalking) publish their whole
model in ``env.unwrapped.P[s][a] = [(prob, next_state, reward, terminated), ...]``
and their start distribution in ``initial_state_distrib`` / ``initial_state_distribution``.
:class:`TabularEnv` turns those into lookup tables and steps a whole batch of
environments with a couple of tensor gathers, instead of one Python call per env.
Observations and actions are integer indices, exactly as
``GymEnv(env_id, categorical_action_encoding=True)`` presents the same env, so a
policy written for one runs unchanged on the other.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

__all__ = ["TabularModel", "TabularEnv"]


@dataclass
class TabularModel:
    """Lookup tables of a finite MDP.

    Attributes:
        next_state: ``[S, A, K]`` long, the K possible successors of each (s, a).
        prob: ``[S, A, K]`` float, their probabilities (padding outcomes have 0).
        reward: ``[S, A, K]`` float.
        terminated: ``[S, A, K]`` bool.
        initial_dist: ``[S]`` float, the start-state distribution.
    """

    next_state: torch.Tensor
    prob: torch.Tensor
    reward: torch.Tensor
    terminated: torch.Tensor
    initial_dist: torch.Tensor

    @property
    def n_states(self) -> int:
        return self.next_state.shape[0]

    @property
    def n_actions(self) -> int:
        return self.next_state.shape[1]

    @property
    def deterministic(self) -> bool:
        return self.next_state.shape[2] == 1

    def step(self, s: torch.Tensor, a: torch.Tensor, generator: torch.Generator | None = None):
        """One step of every (state, action) pair, any batch shape: ``(s', reward,
        terminated)``, the successor drawn from ``prob`` with ``generator`` (one draw per
        pair, in row-major order; none for a deterministic model). :class:`TabularEnv` and
        the batched fast path (``families/gym_batched.py``) both step with this."""
        if self.deterministic:
            k = torch.zeros_like(s)
        else:
            p = self.prob[s, a]
            k = torch.multinomial(p.reshape(-1, p.shape[-1]), 1, generator=generator).view(s.shape)
        return self.next_state[s, a, k], self.reward[s, a, k], self.terminated[s, a, k]

    @classmethod
    def from_gym(cls, env_id_or_env: str | gym.Env, **env_kwargs) -> TabularModel:
        """Reads ``P`` and the start distribution of a gymnasium env
        (``gym.make(env_id, **env_kwargs)``, e.g. ``map_name="8x8", is_slippery=False``).

        Raises:
            ValueError: the env publishes no transition table ``P``.
        """
        env = gym.make(env_id_or_env, **env_kwargs) if isinstance(env_id_or_env, str) else env_id_or_env
        base = env.unwrapped
        P = getattr(base, "P", None)
        if P is None:
            raise ValueError(
                f"{base!r} has no transition table `P`: TabularEnv only works for "
                "toy-text style envs. Use backend='gym' for this environment."
            )
        if not isinstance(base.observation_space, gym.spaces.Discrete) or not isinstance(
            base.action_space, gym.spaces.Discrete
        ):
            raise ValueError(
                f"{base!r} has observation space {base.observation_space} and action space {base.action_space}: "
                "TabularEnv needs Discrete ones. Use backend='gym' for this environment."
            )
        n_states, n_actions = int(base.observation_space.n), int(base.action_space.n)
        k = max(len(P[s][a]) for s in range(n_states) for a in range(n_actions))
        next_state = np.zeros((n_states, n_actions, k), np.int64)
        prob = np.zeros((n_states, n_actions, k), np.float64)
        reward = np.zeros((n_states, n_actions, k), np.float32)
        terminated = np.zeros((n_states, n_actions, k), bool)
        for s in range(n_states):
            for a in range(n_actions):
                for i, (p, s2, r, d) in enumerate(P[s][a]):
                    next_state[s, a, i], prob[s, a, i] = s2, p
                    reward[s, a, i], terminated[s, a, i] = r, d
                # padding outcomes point at the first one, with probability 0
                next_state[s, a, len(P[s][a]) :] = next_state[s, a, 0]
        isd = getattr(base, "initial_state_distrib", None)
        if isd is None:
            isd = getattr(base, "initial_state_distribution", None)
        if isd is None:
            raise ValueError(f"{base!r} publishes no initial state distribution.")
        return cls(
            next_state=torch.as_tensor(next_state),
            prob=torch.as_tensor(prob, dtype=torch.float32),
            reward=torch.as_tensor(reward),
            terminated=torch.as_tensor(terminated),
            initial_dist=torch.as_tensor(np.asarray(isd), dtype=torch.float32),
        )


class TabularEnv(EnvBase):
    """A batch of independent copies of a tabular MDP, stepped with tensor ops.

    Args:
        model (TabularModel): the MDP's tables (see :meth:`TabularModel.from_gym`).
        max_episode_steps (int, optional): truncate episodes after this many steps,
            like gymnasium's ``TimeLimit``. ``None`` never truncates.
        batch_size (int or torch.Size): the number of parallel envs, e.g. ``(16,)``.
        seed (int, optional): seed of the env's own random generator.

    Examples:
        >>> env = TabularEnv.from_gym("Taxi-v4", batch_size=(16,), max_episode_steps=50)
        >>> td = env.rollout(3)
        >>> td["observation"].shape
        torch.Size([16, 3])
    """

    batch_locked = True

    def __init__(
        self,
        model: TabularModel,
        *,
        max_episode_steps: int | None = None,
        batch_size=(),
        seed: int | None = None,
    ):
        batch_size = torch.Size([batch_size] if isinstance(batch_size, int) else batch_size)
        super().__init__(batch_size=batch_size, device="cpu")
        if max_episode_steps is not None and max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be >= 1 or None, got {max_episode_steps}")
        self.model = model
        self.max_episode_steps = max_episode_steps
        S, A = model.n_states, model.n_actions
        self.observation_spec = Composite(
            observation=Categorical(S, shape=batch_size, dtype=torch.int64), shape=batch_size
        )
        self.action_spec = Categorical(A, shape=batch_size, dtype=torch.int64)
        self.reward_spec = Unbounded(shape=(*batch_size, 1), dtype=torch.float32)
        self.done_spec = Composite(
            done=Categorical(2, shape=(*batch_size, 1), dtype=torch.bool),
            terminated=Categorical(2, shape=(*batch_size, 1), dtype=torch.bool),
            truncated=Categorical(2, shape=(*batch_size, 1), dtype=torch.bool),
            shape=batch_size,
        )
        self._rng = torch.Generator()
        self._rng.manual_seed(0 if seed is None else seed)
        self._state = torch.zeros(batch_size, dtype=torch.long)
        self._elapsed = torch.zeros(batch_size, dtype=torch.long)
        self._false = torch.zeros((*batch_size, 1), dtype=torch.bool)

    @classmethod
    def from_gym(cls, env_id: str, **kwargs) -> TabularEnv:
        """Builds the env from a gymnasium id, e.g. ``"Taxi-v4"``."""
        return cls(TabularModel.from_gym(env_id), **kwargs)

    @property
    def state(self) -> torch.Tensor:
        """The current state index of every env (a copy)."""
        return self._state.clone()

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        shape = self.batch_size
        new = torch.multinomial(
            self.model.initial_dist, max(shape.numel(), 1), replacement=True, generator=self._rng
        ).view(shape)
        mask = None if tensordict is None else tensordict.get("_reset", None)
        if mask is None:
            self._state, self._elapsed = new, torch.zeros_like(self._elapsed)
        else:
            mask = mask.reshape(shape)
            self._state = torch.where(mask, new, self._state)
            self._elapsed = torch.where(mask, 0, self._elapsed)
        return TensorDict(
            {
                "observation": self._state.clone(),
                "done": self._false.clone(),
                "terminated": self._false.clone(),
                "truncated": self._false.clone(),
            },
            batch_size=shape,
        )

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get("action").reshape(self.batch_size)
        s2, reward, terminated = self.model.step(self._state, action, self._rng)
        self._elapsed = self._elapsed + 1
        if self.max_episode_steps is not None:
            truncated = (self._elapsed >= self.max_episode_steps) & ~terminated
        else:
            truncated = torch.zeros_like(terminated)
        self._state = s2
        return TensorDict(
            {
                "observation": s2,
                "reward": reward.unsqueeze(-1),
                "done": (terminated | truncated).unsqueeze(-1),
                "terminated": terminated.unsqueeze(-1),
                "truncated": truncated.unsqueeze(-1),
            },
            batch_size=self.batch_size,
        )

    def run_state(self) -> dict[str, torch.Tensor]:
        """What a bit-exact resume needs: the envs' current states, step counts and the
        random generator (``load_run_state`` puts them back)."""
        return {"rng": self._rng.get_state(), "state": self._state.clone(), "elapsed": self._elapsed.clone()}

    def load_run_state(self, state: dict[str, torch.Tensor]) -> None:
        self._rng.set_state(state["rng"])
        self._state.copy_(state["state"])
        self._elapsed.copy_(state["elapsed"])

    def _set_seed(self, seed: int | None) -> None:
        self._rng.manual_seed(0 if seed is None else int(seed))
