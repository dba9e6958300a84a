"""TorchRL's ``Trainer`` for every variant: the optimisation step (gradient clipping per term,
extra BC and inverse-model updates), the expert-demonstration hooks, and resume."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn
from torchrl.checkpoint import Checkpoint, CheckpointError
from torchrl.trainers import OptimizationStepper, Trainer

from torchrl_hybrid.objectives import HybridLoss
from torchrl_hybrid.utils.config import flatten_dict

__all__ = ["CLIP_MODES", "ClippedOptimizationStepper", "attach_demonstrations", "make_trainer", "resume_trainer"]


CLIP_MODES = ("global", "per_group", "per_term")


class ClippedOptimizationStepper(OptimizationStepper):
    """One optimiser step on the sum of the ``loss_*`` terms, with the gradient norm clipped
    to ``max_norm``, then optional extra updates of the BC and inverse-model terms alone.

    ``clip`` says what the clip applies to:

    - ``"global"``: the gradient of the summed loss, over all parameters (what TorchRL's
      default stepper does, and the authors' code);
    - ``"per_group"``: each optimiser parameter group (the policy's, the inverse model's)
      on its own, so that a large policy gradient does not shrink the inverse model's update;
    - ``"per_term"``: each component loss of a :class:`~torchrl_hybrid.objectives.HybridLoss`
      (the RL terms, the inverse model's, the BC term) is differentiated on its own, its
      gradient clipped on its own, and the clipped gradients summed. With a global clip, a
      BC gradient beside an RL gradient 10x larger is scaled down with it; here each term
      keeps up to ``max_norm``. Costs one backward pass per component.

    ``bc_updates`` / ``idm_updates`` (the update-to-data ratio of those terms): after the
    main step, that many more optimiser steps on the BC loss alone (each on a fresh expert
    batch from ``expert_batches``) and on the inverse-model loss alone (on the same agent
    batch), each clipped to ``max_norm``. The RL loss is never repeated (it is on-policy).

    The norms before the clip are returned as ``grad_norm`` (``grad_norm_<group>``,
    ``grad_norm_<term>``), left on the device: unlike TorchRL's default stepper, which reads
    the norm with ``float()``, no update waits for the device.

    Args:
        max_norm: the clip (``None``: no clip, the norm is still reported).
        clip: ``"global"`` | ``"per_group"`` | ``"per_term"``.
        bc_updates: extra BC-only updates per collected batch.
        idm_updates: extra inverse-model-only updates per collected batch.
        expert_batches: a callable giving a fresh expert batch (needed with ``bc_updates``).
    """

    def __init__(
        self,
        max_norm: float | None,
        clip: str = "global",
        *,
        bc_updates: int = 0,
        idm_updates: int = 0,
        expert_batches=None,
    ):
        if clip not in CLIP_MODES:
            raise ValueError(f"clip={clip!r}: choose one of {CLIP_MODES}")
        if bc_updates < 0 or idm_updates < 0:
            raise ValueError(f"bc_updates and idm_updates must be >= 0, got {bc_updates}, {idm_updates}")
        self.max_norm = None if max_norm is None else float(max_norm)
        self.clip, self.bc_updates, self.idm_updates = clip, int(bc_updates), int(idm_updates)
        self.expert_batches = expert_batches

    @staticmethod
    def _clip(params, max_norm: float | None) -> torch.Tensor:
        params = [p for p in params if p.grad is not None]
        if max_norm is not None:
            return nn.utils.clip_grad_norm_(params, max_norm).detach()
        return nn.utils.get_total_norm([p.grad for p in params]).detach()

    @staticmethod
    def _params(trainer: Trainer) -> list[torch.Tensor]:
        return [p for g in trainer.optimizer.param_groups for p in g["params"]]

    def _backward_per_term(self, trainer: Trainer, sub_batch: TensorDictBase) -> TensorDictBase:
        loss_module = trainer.loss_module
        if not hasattr(loss_module, "forward_parts"):
            raise TypeError(f"clip=per_term needs a HybridLoss (forward_parts), got {type(loss_module).__name__}")
        parts = loss_module.forward_parts(sub_batch)
        params = self._params(trainer)
        terms = {name: sum(v for k, v in td.items() if k.startswith("loss")) for name, td in parts.items()}
        terms = {name: t for name, t in terms.items() if isinstance(t, torch.Tensor) and t.requires_grad}
        out = TensorDict({}, [])
        for td in parts.values():
            out.update(td)
        names = list(terms)
        for i, name in enumerate(names):
            grads = torch.autograd.grad(terms[name], params, retain_graph=i < len(names) - 1, allow_unused=True)
            used = [g for g in grads if g is not None]
            norm = nn.utils.get_total_norm(used) if used else torch.zeros(())
            scale = 1.0 if self.max_norm is None else (self.max_norm / (norm + 1e-6)).clamp(max=1.0)
            for p, g in zip(params, grads):
                if g is None:
                    continue
                g = g * scale
                p.grad = g if p.grad is None else p.grad + g
            out[f"grad_norm_{name}"] = norm.detach()
        return out

    def _extra_step(self, trainer: Trainer, loss: torch.Tensor) -> None:
        loss.backward()
        self._clip(self._params(trainer), self.max_norm)
        trainer.optimizer.step()
        trainer.optimizer.zero_grad()

    def step(self, trainer: Trainer, sub_batch: TensorDictBase) -> TensorDictBase:
        if self.clip == "per_term":
            losses_td = self._backward_per_term(trainer, sub_batch)
        else:
            losses_td = trainer.compute_loss(sub_batch)
            sum(v for k, v in losses_td.items() if k.startswith("loss")).backward()
            groups = trainer.optimizer.param_groups
            if self.clip == "per_group":
                for i, group in enumerate(groups):
                    losses_td[f"grad_norm_{group.get('name', i)}"] = self._clip(group["params"], self.max_norm)
            else:
                losses_td["grad_norm"] = self._clip(self._params(trainer), self.max_norm)
        trainer.optimizer.step()
        trainer.optimizer.zero_grad()
        loss_module = trainer.loss_module
        if self.idm_updates and getattr(loss_module, "inverse_dynamics_loss", None) is not None:
            agent = sub_batch.get(loss_module.tensor_keys.agent, sub_batch)
            for _ in range(self.idm_updates):
                out = loss_module.inverse_dynamics_loss(agent)
                self._extra_step(trainer, sum(v for k, v in out.items() if k.startswith("loss")))
        if self.bc_updates and getattr(loss_module, "bc_loss", None) is not None:
            if self.expert_batches is None:
                raise RuntimeError("bc_updates > 0 needs expert_batches (attach_demonstrations sets it)")
            for _ in range(self.bc_updates):
                out = loss_module.bc_loss(self.expert_batches())
                if out["loss_bc"].requires_grad:  # an empty expert batch (rho=visited) gives a constant 0
                    self._extra_step(trainer, out["loss_bc"])
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
    clip: str = "global",
    frame_skip: int = 1,
    bc_updates: int = 0,
    idm_updates: int = 0,
    optim_steps_per_batch: int = 1,
) -> Trainer:
    """A TorchRL ``Trainer`` with ``optim_steps_per_batch`` optimisation steps per collected
    batch (1, the paper's A2C; PPO's epochs x minibatches).

    The step is a :class:`ClippedOptimizationStepper`: ``clip`` = ``"global"`` clips the
    norm of the whole gradient (as TorchRL's default stepper does, without its device sync),
    ``"per_group"`` each optimiser parameter group's, ``"per_term"`` each component loss's;
    ``bc_updates`` / ``idm_updates`` add BC-only / inverse-model-only updates per batch.
    TorchRL's own per-update log of the losses (``auto_log_optim_steps``, a list that
    grows by one entry per update and is never emptied) is off: the learning curve
    (:class:`~torchrl_hybrid.trainers.hooks.MetricsHook`) logs them. With ``frame_skip`` > 1 the
    trainer counts game frames (``frame_skip`` per env step), and ``total_frames``
    is in game frames too.
    """
    stepper = ClippedOptimizationStepper(clip_norm, clip=clip, bc_updates=bc_updates, idm_updates=idm_updates)
    return Trainer(
        collector=collector,
        total_frames=total_frames,
        frame_skip=frame_skip,
        optim_steps_per_batch=optim_steps_per_batch,
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
        InverseModelReadyHook(
            loss.bc_loss,
            "bc_coeff",
            bc_coeff,
            bc_ready_accuracy,
            min_frames=bc_start_frames,
            anneal_frames=bc_anneal_frames,
        ).register(trainer)
    elif bc_start_frames > 0 or bc_anneal_frames > 0:
        DelayedCoefficientHook(
            loss.bc_loss, "bc_coeff", bc_coeff, bc_start_frames, anneal_frames=bc_anneal_frames
        ).register(trainer)
    return buffer


def resume_trainer(
    trainer: Trainer,
    out: Path,
    settings: dict,
    keys: tuple[str, ...],
    ignore: tuple[str, ...] = (),
    defaults: dict | None = None,
) -> int:
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
        raise ValueError(
            f"resume: {ckpt} has no {saved_path.name} beside it, so its settings cannot be checked; "
            "pass overwrite=true to start again there, or choose another out_dir"
        )
    saved = flatten_dict({k: v for k, v in read_json(saved_path, "run config").items() if k in keys})
    now = flatten_dict({k: v for k, v in settings.items() if k in keys})
    for k, v in flatten_dict({k: v for k, v in (defaults or {}).items() if k in keys}).items():
        saved.setdefault(k, v)
    diff = sorted(k for k in set(saved) | set(now) if k not in ignore and saved.get(k) != now.get(k))
    if diff:
        was = ", ".join(f"{k}: {saved.get(k)!r} -> {now.get(k)!r}" for k in diff)
        raise ValueError(
            f"resume: the checkpoint in {out} was written with other settings for {diff} ({was}; "
            f"see {saved_path}); use another out_dir or the same settings"
        )
    if (ckpt / "manifest.json").exists():  # TorchRL's checkpoint format: the list of its components
        read_json(ckpt / "manifest.json", "checkpoint manifest")
    check_memmap_folder(ckpt)
    try:
        trainer.load_from_file(ckpt)
    except CheckpointError as err:
        # checkpoints written before the random state was saved (RandomStateHook) lack only that
        # component: they resume, with a warning; anything else missing stays an error
        missing = set(getattr(err.result, "missing", None) or ())
        if not missing or not missing <= {"trainer_module.random_state"} or getattr(err.result, "incompatible", None):
            raise
        warnings.warn(
            f"resume: {ckpt} was written before checkpoints held the random state; the run goes on "
            "from its weights, optimiser and samplers, but not bit-exactly",
            stacklevel=2,
        )
        trainer.load_from_file(ckpt, strict="ignore")
    frames = int(trainer.collected_frames)
    total = settings.get("total_frames")
    if isinstance(total, int) and frames >= total:  # nothing left to train: finishing would rewrite the run's files
        raise ValueError(
            f"resume=true: the run in {out} is already at {frames:,} frames; raise total_frames "
            f"(now {total:,}) to train further"
        )
    print(f"resume: continuing from {frames:,} frames ({ckpt})", file=sys.stderr)

    def start_bar_at_resumed_frames():  # TorchRL's Trainer.train() opens its bar at 0 even when resumed
        bar = getattr(trainer, "_pbar", None)
        if bar is not None and bar.n < frames:
            bar.update(frames - bar.n)
            bar.refresh()

    trainer.register_op("setup", start_bar_at_resumed_frames)
    return frames
