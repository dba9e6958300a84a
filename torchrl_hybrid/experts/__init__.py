"""Experts that generate demonstrations (computed by our own code, never downloaded)."""
from torchrl_hybrid.experts.tabular import episode_ends, expected_return, optimal_policy, value_iteration

__all__ = ["episode_ends", "expected_return", "optimal_policy", "value_iteration"]
