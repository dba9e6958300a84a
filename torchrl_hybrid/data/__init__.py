"""Expert state-pair datasets (our own format and local Minari datasets), samplers (rho) and demo noise."""

from torchrl_hybrid.data.checks import check_observation_space, check_tabular_transitions, check_trajectories
from torchrl_hybrid.data.expert import (
    EXPERT_ACTION_KEY,
    load_demos,
    make_expert_buffer,
    pairs_from_trajectories,
    save_demos,
    tabular_state_pairs,
    tabular_trajectories,
    validate_demos,
)
from torchrl_hybrid.data.minari import load_minari_demos
from torchrl_hybrid.data.noise import apply_demo_noise
from torchrl_hybrid.data.samplers import CurriculumSampler, VisitedStateSampler

__all__ = [
    "EXPERT_ACTION_KEY",
    "CurriculumSampler",
    "VisitedStateSampler",
    "apply_demo_noise",
    "check_observation_space",
    "check_tabular_transitions",
    "check_trajectories",
    "load_demos",
    "load_minari_demos",
    "make_expert_buffer",
    "pairs_from_trajectories",
    "save_demos",
    "tabular_state_pairs",
    "tabular_trajectories",
    "validate_demos",
]
