"""The one pipeline behind every agent variant: losses and trainer assembly."""
from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torchrl.objectives import A2CLoss, ValueEstimators
from tensordict import TensorDictBase
from torch import nn
from torchrl.checkpoint import Checkpoint
from torchrl.trainers import OptimizationStepper, Trainer

from torchrl_hybrid.modules.inverse_dynamics import InverseDynamicsModel
from torchrl_hybrid.objectives import (
    DualInverseDynamicsLoss,
    ExpertBCLoss,
    HybridLoss,
    InverseDynamicsLoss,
    PolicyEntropyLoss,
)
from torchrl_hybrid.utils.config import flatten_dict

__all__ = ["ClippedOptimizationStepper", "Variant", "attach_demonstrations", "param_groups", "VARIANTS", "get_variant",
           "make_hybrid_loss", "make_trainer", "resume_trainer"]


@dataclass(frozen=True)
class Variant:
    """What an agent variant switches on.

    Attributes:
        rl: train with the A2C loss; without it the policy still gets the
            entropy bonus (the authors' BC baselines are the hybrid agent with
            policy-gradient and value weights 0).
        bc: ``"inferred"`` (clone actions inferred by the inverse model),
            ``"true"`` (clone the true expert actions: IL) or ``None``.
        inverse_model: ``"dual"``, ``"mlp"`` or ``None``.
    """

    name: str
    rl: bool
    bc: str | None
    inverse_model: str | None
    description: str


VARIANTS: dict[str, Variant] = {
    v.name: v
    for v in (
        Variant("hybrid_dual", True, "inferred", "dual", "A2C + BC on actions inferred by the dual model (the paper's agent)"),
        Variant("hybrid_mlp", True, "inferred", "mlp", "A2C + BC on actions inferred by the MLP inverse model"),
        Variant("bc_dual", False, "inferred", "dual", "BC on actions inferred by the dual model, no RL signal"),
        Variant("bc_mlp", False, "inferred", "mlp", "BC on actions inferred by the MLP model, no RL signal"),
        Variant("il", False, "true", None, "BC on the TRUE expert actions (imitation learning upper bound)"),
        Variant("a2c", True, None, None, "plain A2C, ignores the demonstrations"),
    )
}


def get_variant(name: str) -> Variant:
    if name not in VARIANTS:
        raise ValueError(f"unknown variant {name!r}; choose one of: {', '.join(VARIANTS)}")
    return VARIANTS[name]


def make_hybrid_loss(
    variant: Variant,
    actor,
    critic,
    inverse_model: InverseDynamicsModel | None,
    *,
    gamma: float = 0.99,
    critic_coeff: float = 0.2,
    entropy_coeff: float = 0.5,
    idm_action_coeff: float = 2.0,
    idm_embedding_coeff: float = 0.1,
    idm_forward_coeff: float = 0.0,
    bc_coeff: float = 2.0,
    bc_labels: str = "argmax",
    bc_confidence: float = 0.0,
    bc_entropy_floor: float = 0.0,
    expert_action_key: str = "expert_action",
    value_estimator_kwargs: dict | None = None,
) -> HybridLoss:
    """Builds the variant's :class:`HybridLoss`.

    The A2C part is TorchRL's ``A2CLoss`` with the n-step return of each rollout
    (TD(1) over the rollout, bootstrapped from the critic at its end), an L2
    critic loss weighted ``critic_coeff`` and an entropy bonus ``entropy_coeff``.
    """
    if (variant.inverse_model is None) != (inverse_model is None):
        raise ValueError(
            f"variant {variant.name!r} {'needs' if variant.inverse_model else 'takes no'} inverse model"
        )
    rl_loss = None
    if variant.rl:
        rl_loss = A2CLoss(
            actor,
            critic,
            entropy_coeff=entropy_coeff,
            critic_coeff=critic_coeff,
            loss_critic_type="l2",
        )
        rl_loss.make_value_estimator(ValueEstimators.TD1, gamma=gamma, **(value_estimator_kwargs or {}))
    elif entropy_coeff:
        rl_loss = PolicyEntropyLoss(actor, entropy_coeff=entropy_coeff)
    idm_loss = None
    if inverse_model is not None:
        if variant.inverse_model == "dual":
            idm_loss = DualInverseDynamicsLoss(
                inverse_model,
                action_coeff=idm_action_coeff,
                embedding_coeff=idm_embedding_coeff,
                forward_coeff=idm_forward_coeff,
            )
        else:
            idm_loss = InverseDynamicsLoss(inverse_model, action_coeff=idm_action_coeff)
    bc_loss = None
    if variant.bc == "inferred":
        bc_loss = ExpertBCLoss(actor, inverse_model, bc_coeff=bc_coeff, labels=bc_labels, confidence=bc_confidence,
                               entropy_floor=bc_entropy_floor)
    elif variant.bc == "true":
        bc_loss = ExpertBCLoss(actor, None, bc_coeff=bc_coeff, entropy_floor=bc_entropy_floor)
        bc_loss.set_keys(action=expert_action_key)
    return HybridLoss(rl_loss, idm_loss, bc_loss)


class ClippedOptimizationStepper(OptimizationStepper):
    """One optimiser step on the sum of the ``loss_*`` terms, with the gradient norm clipped
    to ``max_norm``: over all parameters (``per_group=False``, TorchRL's default stepper does
    the same), or for each optimiser parameter group on its own (``per_group=True``: e.g. the
    policy's and the inverse model's, so that a large policy-gradient step does not shrink
    the inverse model's update, as a single global clip would).

    The norms before the clip are returned as ``grad_norm`` (or ``grad_norm_<group>``),
    left on the device: unlike TorchRL's default stepper, which reads the norm with
    ``float()``, no update waits for the device.

    Args:
        max_norm: the clip (``None``: no clip, the norm is still reported).
        per_group: clip each parameter group separately.
    """

    def __init__(self, max_norm: float | None, per_group: bool = False):
        self.max_norm = None if max_norm is None else float(max_norm)
        self.per_group = bool(per_group)

    @staticmethod
    def _clip(params, max_norm: float | None) -> torch.Tensor:
        params = [p for p in params if p.grad is not None]
        if max_norm is not None:
            return nn.utils.clip_grad_norm_(params, max_norm).detach()
        return nn.utils.get_total_norm([p.grad for p in params]).detach()

    def step(self, trainer: Trainer, sub_batch: TensorDictBase) -> TensorDictBase:
        losses_td = trainer.compute_loss(sub_batch)
        sum(v for k, v in losses_td.items() if k.startswith("loss")).backward()
        groups = trainer.optimizer.param_groups
        if self.per_group:
            for i, group in enumerate(groups):
                losses_td[f"grad_norm_{group.get('name', i)}"] = self._clip(group["params"], self.max_norm)
        else:
            losses_td["grad_norm"] = self._clip([p for g in groups for p in g["params"]], self.max_norm)
        trainer.optimizer.step()
        trainer.optimizer.zero_grad()
        return losses_td.detach()


def make_trainer(
    *,
    collector,
    loss: HybridLoss,
    optimizer: torch.optim.Optimizer,
    total_frames: int,
    clip_norm: float | None = 0.5,
    logger=None,
    progress_bar: bool = True,
    save_trainer_file=None,
    save_trainer_interval: int = 10**9,
    seed: int | None = None,
    clip_per_group: bool = False,
    frame_skip: int = 1,
) -> Trainer:
    """A TorchRL ``Trainer`` with one optimisation step per collected batch.

    The step is a :class:`ClippedOptimizationStepper`: with ``clip_per_group`` each
    optimiser parameter group's gradient is clipped to ``clip_norm`` on its own, otherwise
    the global norm is (as TorchRL's default stepper does, without its device sync).
    TorchRL's own per-update log of the losses (``auto_log_optim_steps``, a list that
    grows by one entry per update and is never emptied) is off: the learning curve
    (:class:`~torchrl_hybrid.trainers.hooks.MetricsHook`) logs them. With ``frame_skip`` > 1 the
    trainer counts game frames (``frame_skip`` per env step), and ``total_frames``
    is in game frames too.
    """
    stepper = ClippedOptimizationStepper(clip_norm, per_group=clip_per_group and clip_norm is not None)
    return Trainer(
        collector=collector,
        total_frames=total_frames,
        frame_skip=frame_skip,
        optim_steps_per_batch=1,
        loss_module=loss,
        optimizer=optimizer,
        optimization_stepper=stepper,
        logger=logger,
        clip_grad_norm=clip_norm is not None,
        clip_norm=clip_norm,
        progress_bar=progress_bar,
        save_trainer_file=save_trainer_file,
        checkpoint=Checkpoint() if save_trainer_file is not None else None,
        save_trainer_interval=save_trainer_interval,
        log_interval=10**12,
        auto_log_optim_steps=False,
        seed=seed,
    )


def param_groups(loss: HybridLoss) -> list[dict]:
    """Optimiser parameter groups: ``"policy"`` (actor and critic) and
    ``"inverse_model"``, without duplicates."""
    idm = loss.inverse_dynamics_loss
    idm_params = list(idm.parameters()) if idm is not None else []
    idm_ids = {id(p) for p in idm_params}
    policy = [p for p in loss.parameters() if id(p) not in idm_ids]
    groups = [{"params": policy, "name": "policy"}]
    if idm_params:
        groups.append({"params": idm_params, "name": "inverse_model"})
    return groups


def attach_demonstrations(
    trainer: Trainer,
    loss: HybridLoss,
    demos,
    *,
    sampler=None,
    batch_size: int = 32,
    bc_coeff: float = 1.0,
    bc_start_frames: int = 0,
    bc_ready_accuracy: float = 0.0,
    bc_anneal_frames: int = 0,
    include_expert_actions: bool = False,
    device: str | torch.device | None = None,
):
    """Registers what the BC term needs on a trainer: the expert replay buffer
    (``sampler`` = rho; its storage on ``device``), the :class:`ExpertBatchHook`, a
    :class:`CurriculumHook` when the sampler is a curriculum, and a
    :class:`DelayedCoefficientHook` when the BC term starts after
    ``bc_start_frames``, or an :class:`InverseModelReadyHook` when it starts once the
    inverse model's held-out accuracy on the agent's transitions reaches
    ``bc_ready_accuracy`` (and not before ``bc_start_frames``). With
    ``bc_anneal_frames > 0`` the BC weight then falls linearly to 0 over that many
    frames after the switch-on. Returns the buffer."""
    from torchrl_hybrid.data import CurriculumSampler, make_expert_buffer
    from torchrl_hybrid.trainers.hooks import (
        CurriculumHook,
        DelayedCoefficientHook,
        ExpertBatchHook,
        InverseModelReadyHook,
    )

    buffer = make_expert_buffer(demos, sampler=sampler, include_expert_actions=include_expert_actions, device=device)
    ExpertBatchHook(buffer, batch_size).register(trainer)
    if isinstance(sampler, CurriculumSampler):
        CurriculumHook(sampler).register(trainer)
    if bc_ready_accuracy > 0:
        if loss.inverse_dynamics_loss is None:
            raise ValueError("bc_ready_accuracy needs an inverse model (it measures the inverse model's accuracy)")
        InverseModelReadyHook(loss.bc_loss, "bc_coeff", bc_coeff, bc_ready_accuracy, min_frames=bc_start_frames,
                              anneal_frames=bc_anneal_frames).register(trainer)
    elif bc_start_frames > 0 or bc_anneal_frames > 0:
        DelayedCoefficientHook(loss.bc_loss, "bc_coeff", bc_coeff, bc_start_frames,
                               anneal_frames=bc_anneal_frames).register(trainer)
    return buffer


def resume_trainer(trainer: Trainer, out: Path, settings: dict, keys: tuple[str, ...],
                   ignore: tuple[str, ...] = (), defaults: dict | None = None) -> int:
    """Loads ``out/checkpoint`` into ``trainer`` after checking that the run that wrote
    it (``out/config.json``) agrees with ``settings`` on every entry under ``keys``
    (dotted names in ``ignore`` may differ: thread counts, the device). A setting the
    saved config lacks (added to the project after that run started) counts as its
    value in ``defaults``. Returns the frames the checkpoint had collected, 0 when there
    is none (a fresh start)."""
    from torchrl_hybrid.utils.files import check_memmap_folder, read_json

    ckpt, saved_path = out / "checkpoint", out / "config.json"
    if not ckpt.exists():
        print(f"resume: no checkpoint in {out}; starting from scratch", file=sys.stderr)
        return 0
    if not saved_path.exists():
        raise ValueError(f"resume: {ckpt} has no {saved_path.name} beside it, so its settings cannot be checked; "
                         "pass overwrite=true to start again there, or choose another out_dir")
    saved = flatten_dict({k: v for k, v in read_json(saved_path, "run config").items() if k in keys})
    now = flatten_dict({k: v for k, v in settings.items() if k in keys})
    for k, v in flatten_dict({k: v for k, v in (defaults or {}).items() if k in keys}).items():
        saved.setdefault(k, v)
    diff = sorted(k for k in set(saved) | set(now) if k not in ignore and saved.get(k) != now.get(k))
    if diff:
        was = ", ".join(f"{k}: {saved.get(k)!r} -> {now.get(k)!r}" for k in diff)
        raise ValueError(f"resume: the checkpoint in {out} was written with other settings for {diff} ({was}; "
                         f"see {saved_path}); use another out_dir or the same settings")
    if (ckpt / "manifest.json").exists():  # TorchRL's checkpoint format: the list of its components
        read_json(ckpt / "manifest.json", "checkpoint manifest")
    check_memmap_folder(ckpt)
    trainer.load_from_file(ckpt)
    frames = int(trainer.collected_frames)
    print(f"resume: continuing from {frames:,} frames ({ckpt})", file=sys.stderr)

    def start_bar_at_resumed_frames():  # TorchRL's Trainer.train() opens its bar at 0 even when resumed
        bar = getattr(trainer, "_pbar", None)
        if bar is not None and bar.n < frames:
            bar.update(frames - bar.n)
            bar.refresh()

    trainer.register_op("setup", start_bar_at_resumed_frames)
    return frames
