"""Loss modules: inverse dynamics, behavioural cloning on inferred actions, and
their composition with an RL loss."""

from torchrl_hybrid.objectives.bc import ExpertBCLoss, PolicyEntropyLoss
from torchrl_hybrid.objectives.hybrid import HybridLoss
from torchrl_hybrid.objectives.inverse_dynamics import DualInverseDynamicsLoss, InverseDynamicsLoss

__all__ = ["DualInverseDynamicsLoss", "ExpertBCLoss", "HybridLoss", "InverseDynamicsLoss", "PolicyEntropyLoss"]
