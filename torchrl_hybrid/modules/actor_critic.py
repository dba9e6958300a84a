"""Actor and critic builders (TensorDict-wrapped at the edge, plain nn inside)."""
from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import ProbabilisticActor, ValueOperator
from torch.distributions import Categorical

from torchrl_hybrid.modules.encoders import MLPEncoder, OneHotEncoder

__all__ = ["make_mlp_actor_critic", "make_policy", "make_tabular_actor_critic", "tabular_net"]


def tabular_net(n_states: int, out_features: int, identity_embedding: bool = True) -> nn.Sequential:
    """One-hot state -> [trainable S x S embedding initialised to the identity] -> linear.

    This is the authors' Taxi network (REFERENCE.md): the embedding starts as the
    identity, so the net starts as a linear map of the one-hot state, but both
    layers are trained. ``identity_embedding=False`` gives the paper's text
    literally: a single linear map of the one-hot state.
    """
    layers: list[nn.Module] = [OneHotEncoder(n_states)]
    if identity_embedding:
        emb = nn.Linear(n_states, n_states, bias=False)
        with torch.no_grad():
            emb.weight.copy_(torch.eye(n_states))
        layers.append(emb)
    layers.append(nn.Linear(n_states, out_features))
    return nn.Sequential(*layers)


def make_policy(logits_net: nn.Module, in_keys=("observation",)) -> ProbabilisticActor:
    """Wraps a net that outputs action logits as a categorical TorchRL policy that
    writes ``action`` and its ``action_log_prob``."""
    module = TensorDictModule(logits_net, in_keys=list(in_keys), out_keys=["logits"])
    return ProbabilisticActor(
        module,
        in_keys=["logits"],
        out_keys=["action"],
        distribution_class=Categorical,
        return_log_prob=True,
    )


def make_tabular_actor_critic(
    n_states: int, n_actions: int, identity_embedding: bool = True
) -> tuple[ProbabilisticActor, ValueOperator]:
    """Separate actor and critic on the one-hot state (no shared parameters), as in
    the paper's Taxi agent."""
    actor = make_policy(tabular_net(n_states, n_actions, identity_embedding))
    critic = ValueOperator(tabular_net(n_states, 1, identity_embedding), in_keys=["observation"])
    return actor, critic


def make_mlp_actor_critic(
    obs_dim: int, n_actions: int, hidden: int = 64, num_layers: int = 2
) -> tuple[ProbabilisticActor, ValueOperator]:
    """Separate actor and critic MLPs on a vector observation (no shared parameters):
    an :class:`MLPEncoder` then a linear head each. The actor's head starts small
    (gain 0.01, as in Stable-Baselines3) so the first policy is near uniform."""
    head = nn.Linear(hidden, n_actions)
    nn.init.orthogonal_(head.weight, 0.01)
    nn.init.zeros_(head.bias)
    actor = make_policy(nn.Sequential(MLPEncoder(obs_dim, hidden, num_layers), head))
    critic = ValueOperator(nn.Sequential(MLPEncoder(obs_dim, hidden, num_layers), nn.Linear(hidden, 1)),
                           in_keys=["observation"])
    return actor, critic
