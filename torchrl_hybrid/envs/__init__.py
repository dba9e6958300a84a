"""Environments: an exact batched tensor copy of toy-text envs, and builders."""

from torchrl_hybrid.envs.builders import BACKENDS, make_gym_env, observation_kind
from torchrl_hybrid.envs.tabular import TabularEnv, TabularModel

__all__ = ["BACKENDS", "TabularEnv", "TabularModel", "make_gym_env", "observation_kind"]
