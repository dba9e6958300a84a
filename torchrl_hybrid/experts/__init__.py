"""Experts that generate demonstrations (computed or trained by our own code, never
downloaded): the tabular value-iteration expert, expert checkpoints of earlier runs,
and the recording of their state sequences as demos."""

from torchrl_hybrid.experts.checkpoints import load_expert, load_gym_expert
from torchrl_hybrid.experts.recording import record_demos, record_episodes
from torchrl_hybrid.experts.scripted import load_callable_expert
from torchrl_hybrid.experts.tabular import episode_ends, expected_return, optimal_policy, value_iteration

__all__ = [
    "episode_ends",
    "expected_return",
    "load_callable_expert",
    "load_expert",
    "load_gym_expert",
    "optimal_policy",
    "record_demos",
    "record_episodes",
    "value_iteration",
]
