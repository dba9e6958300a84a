"""Inverse-dynamics models M(s, s') -> a: the paper's low-rank dual tensor model and
its MLP baseline, behind one interface.

Both take raw observations (whatever the state encoder eats) and expose

* ``action_logits(obs, next_obs) -> [*B, A]``: logits of P_i(a | s, s');
* ``terms(obs, action, next_obs) -> dict``: everything a loss needs; always
  ``"action_logits"``, plus for the dual model the embeddings ``h_a``,
  ``h_a_hat``, ``h_ds``, ``h_ds_hat`` and, with a forward head,
  ``next_state_logits`` (P_f(s' | s, a));
* ``infer(obs, next_obs) -> [*B]``: M(s, s') = argmax_a P_i(a | s, s'), no gradient.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from torchrl_hybrid.modules.encoders import OneHotEncoder

__all__ = ["InverseDynamicsModel", "DualInverseDynamics", "MLPInverseDynamics", "dual_product"]


def dual_product(hsM: torch.Tensor, hxN: torch.Tensor) -> torch.Tensor:
    """The low-rank dual product from its projections: ``hsM[..., r, :] = h_s M_r`` and
    ``hxN[..., r, :] = h_x N_r`` give F(s, x) = sum_r (h_s M_r) * (h_x N_r). Shared by
    :class:`DualInverseDynamics` and the batched fast path (which projects K agents at once)."""
    return (hsM * hxN).sum(-2)


def _state_projection(encoder: nn.Module, d_state: int) -> nn.Linear:
    """W_s. On a one-hot e_s it is an embedding table, so it is initialised like
    ``nn.Embedding`` (N(0, 1)); the default Linear init (U(+-1/sqrt(n))) makes
    h_s so small that the three-way product of the dual model barely learns."""
    W_s = nn.Linear(int(encoder.out_features), d_state, bias=False)  # type: ignore[arg-type]  # an int on every encoder
    if isinstance(encoder, OneHotEncoder):
        nn.init.normal_(W_s.weight, 0.0, 1.0)
    return W_s


class InverseDynamicsModel(nn.Module):
    """Base class: a model of P_i(a | s, s') over ``n_actions`` discrete actions."""

    n_actions: int
    #: True when :meth:`terms` returns the dual model's embedding terms.
    has_embedding_terms: bool = False
    #: True when :meth:`terms` returns ``next_state_logits``.
    has_forward_head: bool = False

    def action_logits(self, obs: torch.Tensor, next_obs: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def terms(self, obs, action, next_obs) -> dict[str, torch.Tensor]:
        return {"action_logits": self.action_logits(obs, next_obs)}

    def forward(self, obs: torch.Tensor, next_obs: torch.Tensor) -> torch.Tensor:
        return self.action_logits(obs, next_obs)

    @torch.no_grad()
    def infer(self, obs: torch.Tensor, next_obs: torch.Tensor) -> torch.Tensor:
        """The inferred action M(s, s') (argmax, detached)."""
        return self.action_logits(obs, next_obs).argmax(-1)


class DualInverseDynamics(InverseDynamicsModel):
    """The low-rank "dual" tensor model of Guo et al. (2019).

    ``h_s = W_s e_s``, ``h_ds = W_ds (h_s' - h_s)``, ``h_a`` = action embedding, and
    one function for both directions,
    ``F(s, x) = sum_r (h_s M_r) * (h_x N_r)``:
    ``h_a_hat = F(s, ds)`` feeds ``P_i(a|s,s') = softmax(W_a h_a_hat + b_a)`` and
    ``h_ds_hat = F(s, a)`` feeds ``P_f(s'|s,a) = softmax(W_s' (h_ds_hat + W'_ds h_s) + b_s')``.
    The paper's score tensor is ``score(s, a, s') = T x1 h_s x2 h_a x3 h_ds`` with
    ``T[i, k, j] = sum_r M_r[i, k] N_r[j, k]`` (:meth:`full_tensor`), so
    ``score = <h_a, F(s, ds)>``. The paper *assumes* the symmetry
    ``T[:, k, :] = T[:, :, k]`` and, on that ground, uses the same ``M_r, N_r`` for
    the other direction, ``F(s, a)``. The low-rank form does not enforce that
    symmetry: ``<h_ds, F(s, a)>`` contracts ``T`` with ``h_ds`` and ``h_a`` swapped
    (``T x1 h_s x2 h_ds x3 h_a``) and differs from the score for general weights
    (:meth:`forward_score`; tested). Sharing ``M_r, N_r`` ties the two directions'
    parameters; the L1 embedding terms of the loss are what pull the predicted
    embeddings towards the true ones.

    Args:
        encoder: maps observations to ``e_s``; must expose ``out_features``
            (a :class:`~torchrl_hybrid.modules.OneHotEncoder` for Taxi, the
            agent's CNN for Atari).
        n_actions: number of discrete actions.
        d_state: ``d_s``, size of ``h_s`` (paper: 128).
        d: ``d``, size of ``h_a`` and ``h_ds`` (paper: 128).
        rank: ``R`` (paper: 2 for Taxi, 8 for Atari).
        n_states: if given, adds the forward head P_f over this many discrete
            next states (small state spaces only).

    Examples:
        >>> from torchrl_hybrid.modules import OneHotEncoder
        >>> idm = DualInverseDynamics(OneHotEncoder(500), n_actions=6, rank=2)
        >>> s, s2 = torch.tensor([0, 1]), torch.tensor([100, 1])
        >>> idm.action_logits(s, s2).shape
        torch.Size([2, 6])
    """

    has_embedding_terms = True

    def __init__(
        self,
        encoder: nn.Module,
        n_actions: int,
        *,
        d_state: int = 128,
        d: int = 128,
        rank: int = 2,
        n_states: int | None = None,
    ):
        super().__init__()
        if rank < 1:
            raise ValueError(f"rank must be >= 1, got {rank}")
        if n_actions < 2:
            raise ValueError(f"n_actions must be >= 2, got {n_actions}")
        self.encoder = encoder
        self.n_actions, self.rank, self.d_state, self.d = n_actions, rank, d_state, d
        self.W_s = _state_projection(encoder, d_state)
        self.W_ds = nn.Linear(d_state, d, bias=False)
        self.action_embedding = nn.Embedding(n_actions, d)
        # M_r: d_s x d, N_r: d x d, stacked over r; scaled so F(s, x) starts O(1).
        self.M = nn.Parameter(torch.randn(rank, d_state, d) / math.sqrt(d_state))
        self.N = nn.Parameter(torch.randn(rank, d, d) / math.sqrt(d))
        self.action_head = nn.Linear(d, n_actions)  # W_a, b_a
        self.has_forward_head = n_states is not None
        if n_states is not None:
            self.W_ds_prime = nn.Linear(d_state, d, bias=False)  # W'_ds
            self.next_state_head = nn.Linear(d, n_states)  # W_s', b_s'

    def dual(self, h_s: torch.Tensor, h_x: torch.Tensor) -> torch.Tensor:
        """F(s, x) = sum_r (h_s M_r) * (h_x N_r), for h_x either h_ds or h_a."""
        hsM = torch.einsum("...i,rik->...rk", h_s, self.M)
        hxN = torch.einsum("...j,rjk->...rk", h_x, self.N)
        return dual_product(hsM, hxN)

    def embed(self, obs: torch.Tensor, next_obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``h_s`` and ``h_ds``. The encoder sees ``obs`` as given, so an encoder that
        caches its last output (the shared Atari CNN) reuses the policy's features."""
        h_s = self.W_s(self.encoder(obs))
        return h_s, self.W_ds(self.W_s(self.encoder(next_obs)) - h_s)

    def action_logits(self, obs, next_obs):
        h_s, h_ds = self.embed(obs, next_obs)
        return self.action_head(self.dual(h_s, h_ds))

    def terms(self, obs, action, next_obs):
        h_s, h_ds = self.embed(obs, next_obs)
        h_a = self.action_embedding(action.long())
        h_a_hat = self.dual(h_s, h_ds)
        h_ds_hat = self.dual(h_s, h_a)
        out = {
            "action_logits": self.action_head(h_a_hat),
            "h_a": h_a,
            "h_a_hat": h_a_hat,
            "h_ds": h_ds,
            "h_ds_hat": h_ds_hat,
        }
        if self.has_forward_head:
            out["next_state_logits"] = self.next_state_head(h_ds_hat + self.W_ds_prime(h_s))
        return out

    def score(self, obs, action, next_obs) -> torch.Tensor:
        """The tensor score ``T x1 h_s x2 h_a x3 h_ds`` of (s, a, s'), i.e.
        ``<h_a, F(s, ds)>`` (the inverse direction)."""
        h_s, h_ds = self.embed(obs, next_obs)
        return (self.action_embedding(action.long()) * self.dual(h_s, h_ds)).sum(-1)

    def forward_score(self, obs, action, next_obs) -> torch.Tensor:
        """``<h_ds, F(s, a)>`` (the forward direction) ``= T x1 h_s x2 h_ds x3 h_a``.
        Equal to :meth:`score` only where ``T`` is symmetric in its last two
        indices, which the shared ``M_r, N_r`` do not guarantee."""
        h_s, h_ds = self.embed(obs, next_obs)
        return (h_ds * self.dual(h_s, self.action_embedding(action.long()))).sum(-1)

    def full_tensor(self) -> torch.Tensor:
        """The ``d_s x d x d`` core tensor ``T[i, k, j] = sum_r M_r[i, k] N_r[j, k]``."""
        return torch.einsum("rik,rjk->ikj", self.M, self.N)


class MLPInverseDynamics(InverseDynamicsModel):
    """The paper's MLP baseline: 128-d state embeddings of s and s' (shared W_s),
    concatenated, then ``num_layers`` ReLU layers of ``hidden`` units and a linear
    action head.

    Args:
        encoder: maps observations to ``e_s`` (exposes ``out_features``).
        n_actions: number of discrete actions.
        d_state: size of each state embedding (paper: 128).
        hidden: width of the hidden layers (paper: 128).
        num_layers: number of hidden layers (paper: 2).

    Examples:
        >>> from torchrl_hybrid.modules import OneHotEncoder
        >>> idm = MLPInverseDynamics(OneHotEncoder(500), n_actions=6)
        >>> idm.action_logits(torch.tensor([0]), torch.tensor([100])).shape
        torch.Size([1, 6])
    """

    def __init__(
        self,
        encoder: nn.Module,
        n_actions: int,
        *,
        d_state: int = 128,
        hidden: int = 128,
        num_layers: int = 2,
    ):
        super().__init__()
        if num_layers < 1:
            raise ValueError(f"num_layers must be >= 1, got {num_layers}")
        self.encoder = encoder
        self.n_actions = n_actions
        self.W_s = _state_projection(encoder, d_state)
        layers, width = [], 2 * d_state
        for _ in range(num_layers):
            layers += [nn.Linear(width, hidden), nn.ReLU()]
            width = hidden
        self.mlp = nn.Sequential(*layers)
        self.action_head = nn.Linear(hidden, n_actions)

    def action_logits(self, obs, next_obs):
        h = torch.cat([self.W_s(self.encoder(obs)), self.W_s(self.encoder(next_obs))], -1)
        return self.action_head(self.mlp(h))
