"""Actor and critic builders (TensorDict-wrapped at the edge, plain nn inside)."""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule, TensorDictModuleBase
from torch import nn
from torch.distributions import Categorical
from torchrl.modules import ProbabilisticActor, ValueOperator

from torchrl_hybrid.modules.encoders import MLPEncoder, OneHotEncoder

__all__ = ["ExplorerSlots", "make_mlp_actor_critic", "make_policy", "make_tabular_actor_critic", "tabular_net"]


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
    critic = ValueOperator(
        nn.Sequential(MLPEncoder(obs_dim, hidden, num_layers), nn.Linear(hidden, 1)), in_keys=["observation"]
    )
    return actor, critic


class ExplorerSlots(TensorDictModuleBase):
    """The collection policy with ``n_explorers`` env slots acting uniformly at random.

    The first ``n_explorers`` envs of each batch take a uniformly random action instead of the
    policy's, and every step is marked ``explore`` (True in those slots). Their transitions
    show the inverse model every action in the states the agent visits, so its labels are not
    the agent's own favourite action where the policy has narrowed (P_i(a | s, s') ∝ P(s' | s,
    a) pi(a | s): the explorers' pi is uniform). :class:`~torchrl_hybrid.objectives.HybridLoss`
    keeps them out of the RL loss: they are off-policy for A2C and PPO, and importance weights
    1 / pi(a | s) would be unbounded where pi is small; the inverse model trains on every slot.

    Args:
        actor: the policy (writes ``action``).
        n_actions: the number of discrete actions.
        n_explorers: how many env slots explore (the first ones of the batch).
    """

    def __init__(self, actor: TensorDictModuleBase, n_actions: int, n_explorers: int):
        super().__init__()
        if n_explorers < 1:
            raise ValueError(f"n_explorers must be >= 1, got {n_explorers}")
        self.actor, self.n_actions, self.n_explorers = actor, int(n_actions), int(n_explorers)
        self.in_keys = list(actor.in_keys)
        self.out_keys = list(dict.fromkeys([*actor.out_keys, "explore"]))

    def forward(self, tensordict):
        tensordict = self.actor(tensordict)
        action = tensordict.get("action")
        n = action.shape[0]
        if n <= self.n_explorers:
            raise ValueError(f"{n} envs but {self.n_explorers} explorer slots: at least one env must follow the policy")
        explore = torch.zeros(action.shape[: tensordict.batch_dims], dtype=torch.bool, device=action.device)
        explore[: self.n_explorers] = True
        random = torch.randint(self.n_actions, action[: self.n_explorers].shape, device=action.device)
        action = action.clone()
        action[: self.n_explorers] = random.to(action.dtype)
        tensordict.set("action", action)
        tensordict.set("explore", explore)
        return tensordict
