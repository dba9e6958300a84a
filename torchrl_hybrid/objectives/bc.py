"""Behavioural cloning on expert states, with actions inferred by an inverse model."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import ProbabilisticTensorDictSequential
from tensordict.utils import NestedKey
from torchrl.objectives import LossModule

from torchrl_hybrid.modules.inverse_dynamics import InverseDynamicsModel
from torchrl_hybrid.objectives.inverse_dynamics import unwrap_inverse_model

__all__ = ["ExpertBCLoss", "PolicyEntropyLoss"]


class ExpertBCLoss(LossModule):
    """``-bc_coeff * E[log pi(M(s, s') | s)]`` over expert state pairs.

    With an ``inverse_model``, each expert pair ``(s, s')`` is labelled with
    ``M(s, s') = argmax_a P_i(a | s, s')`` (no gradient reaches the inverse model)
    and only ``observation`` and ``("next", observation)`` are read: expert actions
    are never looked at. Without one (the IL baseline, or demonstrations that do
    carry actions) the label is read from the ``action`` key; set it to where the
    true actions live, e.g. ``loss.set_keys(action="expert_action")``.

    Args:
        actor_network: a probabilistic policy (e.g. a TorchRL ``ProbabilisticActor``);
            its distribution is built from the expert states with ``get_dist``.
        inverse_model: the action-inference model M (or a ``TensorDictModule``
            wrapping it, whose two in-keys name s and s'), or ``None`` to clone the
            actions stored under the ``action`` key.

    Keyword Args:
        bc_coeff: weight of the term (authors' Taxi code: 2.0). A schedulable
            buffer: ``loss.bc_coeff = 2.0`` switches it on in place (the paper's
            Atari start delay).
        labels: ``"argmax"`` (the paper: clone ``argmax_a P_i(a | s, s')``) or
            ``"soft"``: the cross-entropy ``-sum_a P_i(a | s, s') log pi(a | s)``, so
            that actions the inverse model cannot tell apart (e.g. NOOP and FIRE while
            the ball is in play) share the probability instead of one being erased.
        confidence: clone only the pairs whose ``max_a P_i`` is at least this (0:
            every pair); the loss averages over the kept pairs.
        entropy_floor: adds ``bc_coeff * relu(entropy_floor - H(pi(.|s)))`` on the
            expert states, so that cloning near-constant labels cannot collapse the
            policy's entropy below the floor (0: off).
        prior_floor: > 0 corrects the labels for the agent's own policy (0: off, the
            paper). Trained on the agent's transitions, the inverse model learns
            ``P_i(a | s, s') ∝ P(s' | s, a) pi(a | s)``: the agent's policy is its prior, so
            where ``(s, s')`` says little the label is the agent's own favourite action,
            and cloning it sharpens the policy further. Corrected, ``P_i(a | s, s') /
            max(pi(a | s), prior_floor)``, renormalised, is the posterior under a uniform
            action prior (``pi`` is the current policy on the expert state, read without
            gradient; the floor bounds the boost of actions the policy almost never takes).

    Returns (``forward``): ``loss_bc`` and the detached diagnostics
    ``bc_log_prob`` (mean log-likelihood of the labels), ``bc_batch_size``,
    ``bc_kept`` (fraction of pairs cloned) and ``bc_policy_entropy`` (on the expert
    states). An empty batch gives a zero loss.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_hybrid.modules import (DualInverseDynamics, OneHotEncoder,
        ...                                     make_tabular_actor_critic)
        >>> actor, _ = make_tabular_actor_critic(10, 4)
        >>> idm = DualInverseDynamics(OneHotEncoder(10), n_actions=4, d_state=8, d=8)
        >>> loss = ExpertBCLoss(actor, idm, bc_coeff=2.0)
        >>> demos = TensorDict({"observation": torch.tensor([1, 2]),
        ...                     ("next", "observation"): torch.tensor([2, 3])}, [2])
        >>> loss(demos)["loss_bc"].backward()
    """

    @dataclass
    class _AcceptedKeys:
        """Tensordict keys read by the loss; rename them with ``set_keys``.

        Attributes:
            observation: the expert state s. Defaults to ``"observation"``.
            next_observation: the expert state s'. Defaults to ``("next", "observation")``.
            action: labels to clone when no inverse model is given. Defaults to ``"action"``.
            inferred_action: where the inferred labels are written in the input
                tensordict, for inspection. Defaults to ``"inferred_action"``.
        """

        observation: NestedKey = "observation"
        next_observation: NestedKey = ("next", "observation")
        action: NestedKey = "action"
        inferred_action: NestedKey = "inferred_action"

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys
    out_keys = ["loss_bc", "bc_log_prob", "bc_batch_size", "bc_kept", "bc_policy_entropy"]
    functional = False  # the policy and the inverse model stay the caller's modules
    _schedulable_buffers = frozenset({"bc_coeff"})

    def __init__(
        self,
        actor_network: ProbabilisticTensorDictSequential,
        inverse_model: InverseDynamicsModel | None = None,
        *,
        bc_coeff: float = 1.0,
        labels: str = "argmax",
        confidence: float = 0.0,
        entropy_floor: float = 0.0,
        prior_floor: float = 0.0,
    ):
        super().__init__()
        if not hasattr(actor_network, "get_dist"):
            raise TypeError("actor_network must be a probabilistic policy with a `get_dist` method")
        if labels not in ("argmax", "soft"):
            raise ValueError(f"labels={labels!r}: choose argmax (the paper) or soft")
        if not 0.0 <= confidence <= 1.0:
            raise ValueError(f"confidence={confidence} must be in [0, 1]")
        if entropy_floor < 0:
            raise ValueError(f"entropy_floor={entropy_floor} must be >= 0")
        if not 0.0 <= prior_floor <= 1.0:
            raise ValueError(f"prior_floor={prior_floor} must be in [0, 1] (0: no prior correction)")
        if inverse_model is None and (labels != "argmax" or confidence > 0 or prior_floor > 0):
            raise ValueError(
                "soft labels, a confidence gate and the prior correction need an inverse model (they read P_i)"
            )
        in_keys = None
        if inverse_model is not None:
            inverse_model, in_keys = unwrap_inverse_model(inverse_model)
        self.actor_network = actor_network
        self.inverse_model = inverse_model
        if in_keys is not None:
            self.set_keys(observation=in_keys[0], next_observation=in_keys[1])
        self.labels_mode, self.confidence, self.entropy_floor = labels, float(confidence), float(entropy_floor)
        self.prior_floor = float(prior_floor)
        self.register_coeff_buffer("bc_coeff", bc_coeff)

    @property
    def in_keys(self):
        keys = list(self.actor_network.in_keys)
        if self.inverse_model is not None:
            keys.append(self.tensor_keys.next_observation)
        else:
            keys.append(self.tensor_keys.action)
        return list(dict.fromkeys(keys))

    def labels(self, tensordict: TensorDictBase) -> torch.Tensor:
        """The actions to clone: M(s, s') with an inverse model, else the action key."""
        if self.inverse_model is None:
            return tensordict.get(self.tensor_keys.action).long()
        obs = tensordict.get(self.tensor_keys.observation)
        next_obs = tensordict.get(self.tensor_keys.next_observation)
        return self.inverse_model.infer(obs, next_obs)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        n = tensordict.batch_size.numel()
        if n == 0:
            zero = torch.zeros((), device=self.bc_coeff.device)
            return TensorDict(
                {k: zero for k in ("loss_bc", "bc_log_prob", "bc_batch_size", "bc_kept", "bc_policy_entropy")}, []
            )
        # Only the actor's inputs go in: the actor may write its own "action". The
        # policy runs first so that an encoder shared with the inverse model can hand
        # its features to the (no-grad) labelling pass.
        dist = self.actor_network.get_dist(tensordict.select(*self.actor_network.in_keys))
        if self.inverse_model is None:
            labels, p_i = self.labels(tensordict), None
        else:
            with torch.no_grad():
                p_i = self.inverse_model.action_logits(
                    tensordict.get(self.tensor_keys.observation), tensordict.get(self.tensor_keys.next_observation)
                ).softmax(-1)
                if self.prior_floor > 0:  # divide out the agent's own policy, the inverse model's prior
                    p_i = p_i / dist.probs.detach().clamp_min(self.prior_floor)
                    p_i = p_i / p_i.sum(-1, keepdim=True)
            labels = p_i.argmax(-1)
            tensordict.set(self.tensor_keys.inferred_action, labels)
        log_prob = dist.log_prob(labels)
        if self.labels_mode == "soft":
            per_pair = -(p_i * dist.logits.log_softmax(-1)).sum(-1)  # cross-entropy to P_i
        else:
            per_pair = -log_prob
        if p_i is None or self.confidence <= 0:
            loss, kept = per_pair.mean(), torch.ones_like(per_pair)
        else:
            kept = (p_i.max(-1).values >= self.confidence).float()
            loss = (per_pair * kept).sum() / kept.sum().clamp_min(1.0)
        entropy = dist.entropy()
        if self.entropy_floor > 0:
            loss = loss + (self.entropy_floor - entropy).clamp_min(0.0).mean()
        return TensorDict(
            {
                "loss_bc": self.bc_coeff * loss,
                "bc_log_prob": log_prob.mean().detach(),
                "bc_batch_size": torch.tensor(float(n)),
                "bc_kept": kept.mean().detach(),
                "bc_policy_entropy": entropy.mean().detach(),
            },
            [],
        )


class PolicyEntropyLoss(LossModule):
    """``-entropy_coeff * E[H(pi(.|s))]`` on the agent's own states.

    The BC-only baselines keep the A2C entropy bonus (the authors' BC-Dual is the
    hybrid agent with the policy-gradient and value weights set to 0), so they
    keep exploring and their inverse model keeps getting varied transitions.

    Args:
        actor_network: a probabilistic policy with ``get_dist``.

    Keyword Args:
        entropy_coeff: weight of the bonus (a schedulable buffer).

    The loss reads the actor's own ``in_keys``; it has no keys of its own to rename.
    """

    out_keys = ["loss_entropy", "entropy"]
    functional = False
    _schedulable_buffers = frozenset({"entropy_coeff"})

    def __init__(self, actor_network: ProbabilisticTensorDictSequential, *, entropy_coeff: float = 0.01):
        super().__init__()
        self.actor_network = actor_network
        self.register_coeff_buffer("entropy_coeff", entropy_coeff)

    @property
    def in_keys(self):
        return list(self.actor_network.in_keys)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        dist = self.actor_network.get_dist(tensordict.select(*self.actor_network.in_keys))
        entropy = dist.entropy().mean()
        return TensorDict({"loss_entropy": -self.entropy_coeff * entropy, "entropy": entropy.detach()}, [])
