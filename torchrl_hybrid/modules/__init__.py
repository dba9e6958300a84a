"""Networks: plain ``nn.Module``s (tensors in, tensors out) and their TorchRL wrappers."""

from torchrl_hybrid.modules.actor_critic import (
    ExplorerSlots,
    make_mlp_actor_critic,
    make_policy,
    make_tabular_actor_critic,
    tabular_net,
)
from torchrl_hybrid.modules.atari import AtariCollectionPolicy, AtariEncoder, make_atari_actor_critic
from torchrl_hybrid.modules.encoders import MLPEncoder, OneHotEncoder
from torchrl_hybrid.modules.inverse_dynamics import (
    DualInverseDynamics,
    InverseDynamicsModel,
    MLPInverseDynamics,
    dual_product,
)

__all__ = [
    "AtariEncoder",
    "make_atari_actor_critic",
    "AtariCollectionPolicy",
    "ExplorerSlots",
    "DualInverseDynamics",
    "InverseDynamicsModel",
    "MLPEncoder",
    "MLPInverseDynamics",
    "OneHotEncoder",
    "dual_product",
    "make_mlp_actor_critic",
    "make_policy",
    "make_tabular_actor_critic",
    "tabular_net",
]
