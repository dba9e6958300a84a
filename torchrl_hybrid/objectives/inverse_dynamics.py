"""Inverse-dynamics losses, trained on the agent's own (s, a, s') transitions."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torchrl.objectives import LossModule

from torchrl_hybrid.modules.inverse_dynamics import InverseDynamicsModel

__all__ = ["InverseDynamicsLoss", "DualInverseDynamicsLoss", "unwrap_inverse_model"]


def unwrap_inverse_model(inverse_model) -> tuple[InverseDynamicsModel, list | None]:
    """The :class:`InverseDynamicsModel` behind ``inverse_model`` and, when it came
    wrapped in a ``TensorDictModule(model, in_keys=[s_key, s_next_key], ...)``, the
    wrapper's two in-keys (the loss then reads s and s' there)."""
    if isinstance(inverse_model, InverseDynamicsModel):
        return inverse_model, None
    inner = getattr(inverse_model, "module", None)
    if isinstance(inverse_model, TensorDictModuleBase) and isinstance(inner, InverseDynamicsModel):
        in_keys = list(inverse_model.in_keys)
        if len(in_keys) != 2:
            raise ValueError(
                f"a TensorDictModule-wrapped inverse model needs exactly two in_keys (s, s'), got {in_keys}; "
                "e.g. TensorDictModule(idm, in_keys=['observation', ('next', 'observation')], out_keys=['idm_logits'])"
            )
        return inner, in_keys
    raise TypeError(
        f"inverse_model must be an InverseDynamicsModel (DualInverseDynamics, MLPInverseDynamics) or a "
        f"TensorDictModule wrapping one, got {type(inverse_model).__name__}"
    )


class InverseDynamicsLoss(LossModule):
    """``-log P_i(a | s, s')`` for any :class:`InverseDynamicsModel` (dual or MLP).

    The pair is ``(observation, ("next", observation))`` of one transition, as a
    TorchRL collector writes it: ``("next", ...)`` always holds the true successor
    of the step, also when the env was reset right after it, so a pair never
    spans two episodes. Data built any other way can mark pairs to skip with the
    ``mask`` key (``True`` = use).

    Args:
        inverse_model: the model to train, or a ``TensorDictModule`` wrapping it
            (``in_keys=[s_key, s_next_key]``: the loss reads s and s' there).

    Keyword Args:
        action_coeff: weight of ``-log P_i`` (the authors' Taxi code: 2.0). A
            schedulable buffer: ``loss.action_coeff = 0.5`` updates it in place.

    The model stays a plain submodule (``functional`` is ``False``): its parameters
    are the ones the caller holds, so a BC loss or labeller sharing the model sees
    the weights this loss trains; build the optimiser over them directly.

    Returns (``forward``): ``loss_inverse`` and the detached diagnostics
    ``idm_accuracy`` (argmax P_i == a on this batch) and ``idm_entropy``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_hybrid.modules import MLPInverseDynamics, OneHotEncoder
        >>> loss = InverseDynamicsLoss(MLPInverseDynamics(OneHotEncoder(10), 4))
        >>> td = TensorDict({"observation": torch.tensor([1, 2]), "action": torch.tensor([0, 3]),
        ...                  ("next", "observation"): torch.tensor([2, 2])}, [2])
        >>> sorted(loss(td).keys())
        ['idm_accuracy', 'idm_entropy', 'loss_inverse']
    """

    @dataclass
    class _AcceptedKeys:
        """Tensordict keys read by the loss; rename them with ``set_keys``.

        Attributes:
            observation: the state s. Defaults to ``"observation"``.
            next_observation: the state s'. Defaults to ``("next", "observation")``.
            action: the action taken (integer index). Defaults to ``"action"``.
            mask: optional boolean entry, ``True`` for pairs to train on.
                Defaults to ``None`` (every pair).
        """

        observation: NestedKey = "observation"
        next_observation: NestedKey = ("next", "observation")
        action: NestedKey = "action"
        mask: NestedKey | None = None

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys
    functional = False
    _schedulable_buffers = frozenset({"action_coeff"})

    def __init__(self, inverse_model, *, action_coeff: float = 1.0):
        super().__init__()
        inverse_model, in_keys = unwrap_inverse_model(inverse_model)
        self.inverse_model = inverse_model
        if in_keys is not None:
            self.set_keys(observation=in_keys[0], next_observation=in_keys[1])
        self.register_coeff_buffer("action_coeff", action_coeff)

    @property
    def in_keys(self):
        keys = [self.tensor_keys.observation, self.tensor_keys.next_observation, self.tensor_keys.action]
        if self.tensor_keys.mask is not None:
            keys.append(self.tensor_keys.mask)
        return keys

    def _select(self, tensordict: TensorDictBase):
        obs = tensordict.get(self.tensor_keys.observation)
        next_obs = tensordict.get(self.tensor_keys.next_observation)
        action = tensordict.get(self.tensor_keys.action)
        if action.dtype.is_floating_point or action.shape != tensordict.shape:
            raise ValueError(
                f"{self.tensor_keys.action!r} must hold integer action indices of shape "
                f"{tuple(tensordict.shape)}, got dtype {action.dtype} and shape {tuple(action.shape)}; "
                "use categorical (index) actions, e.g. GymEnv(..., categorical_action_encoding=True)."
            )
        if self.tensor_keys.mask is not None:
            mask = tensordict.get(self.tensor_keys.mask).reshape(tensordict.shape).bool()
            obs, next_obs, action = obs[mask], next_obs[mask], action[mask]
        else:
            n = tensordict.batch_size.numel()
            obs = obs.reshape(n, *obs.shape[tensordict.ndim :])
            next_obs = next_obs.reshape(n, *next_obs.shape[tensordict.ndim :])
            action = action.reshape(n)
        return obs, action.long(), next_obs

    def _terms(self, terms: dict, obs, action, next_obs) -> TensorDict:
        logits = terms["action_logits"]
        logp = logits.log_softmax(-1)
        out = TensorDict(
            {
                "loss_inverse": self.action_coeff * F.nll_loss(logp, action),
                "idm_accuracy": (logits.argmax(-1) == action).float().mean().detach(),
                "idm_entropy": -(logp.exp() * logp).sum(-1).mean().detach(),
            },
            [],
        )
        return out

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        obs, action, next_obs = self._select(tensordict)
        if action.numel() == 0:
            zero = torch.zeros((), device=action.device)
            return TensorDict({k: zero for k in self.out_keys}, [])
        terms = self.inverse_model.terms(obs, action, next_obs)
        return self._terms(terms, obs, action, next_obs)

    @property
    def out_keys(self):
        return ["loss_inverse", "idm_accuracy", "idm_entropy"]


class DualInverseDynamicsLoss(InverseDynamicsLoss):
    """The paper's dual-model loss:

    ``action_coeff * -log P_i(a|s,s')
    + embedding_coeff * (|h_a - h_a_hat|_1 + |h_ds - h_ds_hat|_1)
    + forward_coeff * -log P_f(s'|s,a)``.

    The L1 norms are averaged over the embedding dimension (``|x|_1 / d``) so that
    ``embedding_coeff`` does not scale with ``d``. The paper trains ``L_act``
    (``forward_coeff=0``, the default); ``forward_coeff > 0`` needs a model built
    with ``n_states`` and integer (state index) observations.

    Args:
        inverse_model: a :class:`~torchrl_hybrid.modules.DualInverseDynamics`.

    Keyword Args:
        action_coeff: weight of the action term (authors' Taxi code: 2.0).
        embedding_coeff: weight of the two L1 embedding terms (authors: 0.1).
        forward_coeff: weight of ``-log P_f`` (authors: 0).

    The three coefficients are schedulable buffers (``loss.embedding_coeff = 0.0``).

    Returns (``forward``): ``loss_inverse``, ``loss_action_embedding``,
    ``loss_state_embedding``, ``loss_forward`` (when ``forward_coeff > 0``) and the
    detached ``idm_accuracy``, ``idm_entropy``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_hybrid.modules import DualInverseDynamics, OneHotEncoder
        >>> idm = DualInverseDynamics(OneHotEncoder(10), n_actions=4, rank=2, d_state=8, d=8)
        >>> loss = DualInverseDynamicsLoss(idm, action_coeff=2.0, embedding_coeff=0.1)
        >>> td = TensorDict({"observation": torch.tensor([1, 2]), "action": torch.tensor([0, 3]),
        ...                  ("next", "observation"): torch.tensor([2, 2])}, [2])
        >>> out = loss(td)
        >>> sum(v for k, v in out.items() if k.startswith("loss_")).backward()
    """

    _schedulable_buffers = frozenset({"embedding_coeff", "forward_coeff"})

    def __init__(
        self,
        inverse_model,
        *,
        action_coeff: float = 1.0,
        embedding_coeff: float = 0.1,
        forward_coeff: float = 0.0,
    ):
        super().__init__(inverse_model, action_coeff=action_coeff)
        inverse_model = self.inverse_model
        if not inverse_model.has_embedding_terms:
            raise ValueError(
                f"{type(inverse_model).__name__} has no embedding terms; use "
                "InverseDynamicsLoss for it (e.g. the MLP baseline), or a DualInverseDynamics model."
            )
        if forward_coeff > 0 and not inverse_model.has_forward_head:
            raise ValueError(
                "forward_coeff > 0 needs the forward head P_f: build the model with "
                "DualInverseDynamics(..., n_states=<number of states>)."
            )
        self.register_coeff_buffer("embedding_coeff", embedding_coeff)
        self.register_coeff_buffer("forward_coeff", forward_coeff)
        self._use_forward = forward_coeff > 0

    @property
    def out_keys(self):
        keys = ["loss_inverse", "loss_action_embedding", "loss_state_embedding"]
        if self._use_forward:
            keys.append("loss_forward")
        return keys + ["idm_accuracy", "idm_entropy"]

    def _terms(self, terms, obs, action, next_obs):
        out = super()._terms(terms, obs, action, next_obs)
        out["loss_action_embedding"] = self.embedding_coeff * F.l1_loss(terms["h_a_hat"], terms["h_a"])
        out["loss_state_embedding"] = self.embedding_coeff * F.l1_loss(terms["h_ds_hat"], terms["h_ds"])
        if self._use_forward:
            if next_obs.dtype.is_floating_point or next_obs.ndim != 1:
                raise ValueError(
                    "the forward term -log P_f(s'|s,a) needs integer state-index observations; "
                    f"got dtype {next_obs.dtype}, shape {tuple(next_obs.shape)}"
                )
            out["loss_forward"] = self.forward_coeff * F.cross_entropy(terms["next_state_logits"], next_obs.long())
        return out
