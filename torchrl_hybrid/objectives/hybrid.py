"""Composition of an RL loss with the inverse-dynamics and expert BC losses."""

from __future__ import annotations

from dataclasses import dataclass

from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torchrl.objectives import LossModule

__all__ = ["HybridLoss"]


class HybridLoss(LossModule):
    """Runs each component loss on its own batch and merges their outputs.

    The input holds two sub-tensordicts with independent batch sizes: the
    agent's own transitions (``agent`` key) feed the RL loss and the inverse-
    dynamics loss, the expert pairs (``expert`` key) feed the BC loss. This is
    the paper's objective ``U_hybrid`` plus the inverse-model loss. Any part may
    be ``None``: ``rl_loss=None`` gives the BC-only baselines, ``bc_loss=None``
    plain RL (then a plain collector batch is accepted too). The components stay ordinary TorchRL losses; use them directly in
    another trainer if this container does not fit.

    Args:
        rl_loss: e.g. TorchRL's ``A2CLoss`` or ``ClipPPOLoss``.
        inverse_dynamics_loss: e.g. :class:`DualInverseDynamicsLoss`.
        bc_loss: :class:`ExpertBCLoss`.

    Examples:
        >>> # batch = TensorDict({"agent": collector_batch, "expert": expert_batch}, [])
        >>> # losses = HybridLoss(a2c, idm_loss, bc_loss)(batch)
    """

    @dataclass
    class _AcceptedKeys:
        """Attributes:
        agent: sub-tensordict with the agent's transitions. Defaults to ``"agent"``.
        expert: sub-tensordict with the expert pairs. Defaults to ``"expert"``.
        explore: marks the agent's transitions made by explorer slots (uniformly random
            actions), which the RL loss leaves out. Defaults to ``"explore"``.
        """

        agent: NestedKey = "agent"
        expert: NestedKey = "expert"
        explore: NestedKey = "explore"

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys
    functional = False  # a container: its components own their parameters

    def __init__(
        self,
        rl_loss: LossModule | None = None,
        inverse_dynamics_loss: LossModule | None = None,
        bc_loss: LossModule | None = None,
    ):
        super().__init__()
        if rl_loss is None and bc_loss is None:
            raise ValueError("HybridLoss needs at least an rl_loss or a bc_loss to train a policy")
        self.rl_loss = rl_loss
        self.inverse_dynamics_loss = inverse_dynamics_loss
        self.bc_loss = bc_loss

    def make_value_estimator(self, value_type=None, **hyperparams):
        if self.rl_loss is not None:
            self.rl_loss.make_value_estimator(value_type, **hyperparams)
        return self

    @property
    def in_keys(self):
        return [self.tensor_keys.agent, self.tensor_keys.expert]

    def forward_parts(self, tensordict: TensorDictBase) -> dict[str, TensorDictBase]:
        """Each component's outputs on its own batch: ``{"rl": ..., "inverse_model": ...,
        "bc": ...}`` (absent components left out). :meth:`forward` merges them; an optimiser
        step that treats the terms apart (e.g. clips the BC gradient on its own) reads them
        here."""
        parts = {}
        for name, loss, key in (
            ("rl", self.rl_loss, self.tensor_keys.agent),
            ("inverse_model", self.inverse_dynamics_loss, self.tensor_keys.agent),
            ("bc", self.bc_loss, self.tensor_keys.expert),
        ):
            if loss is None:
                continue
            sub = tensordict.get(key, None)
            if sub is None and key == self.tensor_keys.agent and self.tensor_keys.expert not in tensordict.keys():
                sub = tensordict  # a plain collector batch: no expert part
            if sub is None:
                raise KeyError(
                    f"{type(loss).__name__} needs the sub-tensordict {key!r}; the trainer's "
                    "ExpertBatchHook builds it (or pass TensorDict({'agent': ..., 'expert': ...}, []))."
                )
            if name == "rl":
                policy = self._policy_slots(sub)
                if (
                    policy.batch_size.numel() == 0
                ):  # a minibatch of explorer transitions only (PPO): nothing to learn from
                    parts[name] = self._zero_loss(loss(sub))
                    continue
                sub = policy
            parts[name] = loss(sub)
        return parts

    @staticmethod
    def _zero_loss(out: TensorDictBase) -> TensorDictBase:
        """The RL loss's entries with every ``loss_*`` term zero but still in the graph (computed
        on off-policy rows, then multiplied by 0): the keys, the sum and each term's backward stay
        as in any other step, and no gradient comes from it."""
        return out.named_apply(
            lambda k, v: v.nan_to_num(0.0, 0.0, 0.0) * 0.0 if k.startswith("loss_") else v, filter_empty=False
        )

    def _policy_slots(self, sub: TensorDictBase) -> TensorDictBase:
        """The agent's transitions without the explorer slots' (``explore``, written by
        :class:`~torchrl_hybrid.modules.ExplorerSlots`): they are off-policy for the RL loss.
        An ``[envs, time]`` batch keeps whole env rows, so the returns stay per trajectory."""
        key = self.tensor_keys.explore
        if key not in sub.keys():
            return sub
        explore = sub.get(key)
        keep = ~explore[:, 0] if sub.ndim == 2 else ~explore.reshape(sub.shape)
        # integer rows: one device-to-host sync (a boolean mask on a TensorDict reads it once per entry)
        return sub[keep.nonzero().squeeze(-1)]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        out = TensorDict({}, [])
        for part in self.forward_parts(tensordict).values():
            for name, value in part.items():
                if name in out.keys():
                    raise RuntimeError(f"two component losses both return {name!r}")
                out.set(name, value)
        return out
