"""Expert state-pair datasets, samplers (rho) and demo noise."""
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
from torchrl_hybrid.data.noise import apply_demo_noise
from torchrl_hybrid.data.samplers import CurriculumSampler, VisitedStateSampler

__all__ = [
    "EXPERT_ACTION_KEY",
    "CurriculumSampler",
    "VisitedStateSampler",
    "apply_demo_noise",
    "load_demos",
    "make_expert_buffer",
    "pairs_from_trajectories",
    "save_demos",
    "tabular_state_pairs",
    "tabular_trajectories",
    "validate_demos",
]
