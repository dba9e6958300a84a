"""One run assembly for every env: build, resume, train, finish.

An env family plugs in through :class:`EnvFamily`: it builds the envs and demos
(:meth:`EnvFamily.setup`), the actor, critic and the inverse model's state encoder
(:meth:`EnvFamily.networks`, e.g. the one-hot encoder for toy-text, an MLP for
vector observations, the paper's CNN for Atari), the collector, its own hooks,
the evaluation columns and the final evaluation. Everything else is written once,
here: the variant's inverse model, losses and optimiser, the logger, TorchRL's
``Trainer`` with its checkpoints, the expert buffer and BC schedule, the learning
curve, resuming, and ``summary.json`` / ``model.pt`` / ``learning_curve.png``.

The gymnasium family (Taxi, FrozenLake, CartPole, ...) is
:class:`~torchrl_hybrid.families.gym.GymFamily`, Atari's is
:class:`~torchrl_hybrid.families.atari.AtariFamily`; ``train_gym(cfg)`` and
``train_atari(cfg)`` are ``train_run(cfg, family)``.

Process-wide settings (torch threads, log levels, progress-bar refresh) are not
changed here: the recipes set them (:func:`~torchrl_hybrid.utils.process.configure_process`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import torch
from torchrl.record.loggers import get_logger
from torchrl.trainers import UpdateWeights

from torchrl_hybrid.collectors.workers import BatchToDeviceHook, worker_weights_getter
from torchrl_hybrid.data import EXPERT_ACTION_KEY
from torchrl_hybrid.modules import DualInverseDynamics, ExplorerSlots, MLPInverseDynamics
from torchrl_hybrid.trainers.config import (
    BC_LABELS,
    LOGGERS,
    WARMUP_UPDATES,
    DemoConfig,
    LoggerConfig,
    LossConfig,
    OptimConfig,
    PPOConfig,
    RunConfig,
)
from torchrl_hybrid.trainers.hooks import LRWarmupHook, MetricsHook, MinibatchHook
from torchrl_hybrid.trainers.trainer import attach_demonstrations, make_trainer, resume_trainer
from torchrl_hybrid.utils.device import resolve_device
from torchrl_hybrid.utils.files import check_resume_target, prepare_out_dir
from torchrl_hybrid.utils.plotting import plot_learning_curve
from torchrl_hybrid.variants import Variant, get_variant, make_hybrid_loss, param_groups

__all__ = [
    "RunConfig",
    "LossConfig",
    "OptimConfig",
    "LoggerConfig",
    "DemoConfig",
    "PPOConfig",
    "LOGGERS",
    "BC_LABELS",
    "EnvFamily",
    "Setup",
    "Networks",
    "Run",
    "build_run",
    "train_run",
    "finish_run",
    "make_inverse_model",
    "load_init_weights",
]


@dataclass
class Setup:
    """What :meth:`EnvFamily.setup` builds: the training env (or the collector's envs),
    the action count and the demos (``None`` for plain A2C). A family keeps what its later
    steps need in typed fields of its own subclass (``GymSetup``, ``AtariSetup``)."""

    env: Any
    n_actions: int
    demos: Any = None
    n_states: int | None = None  # tabular envs: the state count (the inverse model's forward head)


@dataclass
class Networks:
    """What :meth:`EnvFamily.networks` builds. ``inverse_encoder()`` gives the inverse
    model's state encoder: a fresh one (toy-text, vector observations) or the actor's
    shared one (Atari). ``collection_policy`` defaults to the actor."""

    actor: Any
    critic: Any
    inverse_encoder: Callable[[], torch.nn.Module]
    collection_policy: Any = None
    encoder: Any = None  # the shared encoder, where there is one


class EnvFamily:
    """What an env brings to :func:`build_run`. Subclasses set the class attributes and
    override the methods that raise here."""

    name = "env"
    resume_keys: tuple[str, ...] = ()  # a checkpoint is resumed only by a run agreeing on these
    resume_ignore: tuple[str, ...] = ()  # dotted names that may differ on resume (thread counts)
    init_keys: tuple[str, ...] = ()  # dotted names an init_from model.pt must agree on (the env, the networks' shapes)
    checkpoints_per_run = 4
    return_key: Any = ("next", "episode_reward")
    pbar_keys: tuple[str, ...] = ("return_mean",)
    loss_extra: Mapping[str, Any] = MappingProxyType({})  # more make_hybrid_loss arguments (read-only)

    def setup(self, cfg, variant: Variant, device: torch.device, generator: torch.Generator) -> Setup:
        raise NotImplementedError

    def networks(self, cfg, variant: Variant, setup: Setup) -> Networks:
        raise NotImplementedError

    def frame_skip(self, setup: Setup) -> int:
        """Game frames per agent step; ``total_frames`` and the BC schedule count game frames."""
        return 1

    def collector(self, cfg, setup: Setup, policy, device: torch.device, total_steps: int):
        raise NotImplementedError

    def small_model(self, cfg) -> bool:
        """Whether the networks are so small that ``device=auto`` keeps them on the CPU: with
        a GPU, every env step would cost a host-device round trip larger than their work."""
        return False

    def uses_workers(self, cfg) -> bool:
        """Whether the collector steps the envs in other processes (their policy copies get
        the learner's weights after every batch)."""
        return False

    def sampler(self, cfg, setup: Setup):
        """rho: the expert buffer's sampler (``None``: uniform)."""
        return None

    def register_hooks(self, run: Run) -> None:
        """Hooks of this family, registered before the learning curve's."""

    def register_late_hooks(self, run: Run) -> None:
        """Hooks registered after the learning curve's (e.g. the envs' run state)."""

    def evaluator(self, run: Run) -> Callable[[], dict[str, float]]:
        """Extra learning-curve columns, computed every ``logger.log_every_frames``."""
        return dict

    def finish(self, run: Run) -> tuple[dict, dict]:
        """After training: the summary's family entries and ``model.pt``'s extra entries."""
        return {}, {}

    def experiment_name(self, cfg) -> str:
        return f"{cfg.variant}_s{cfg.seed}"

    def title(self, cfg) -> str:
        return f"{cfg.variant}, seed {cfg.seed}"

    def plot_kwargs(self, run: Run, summary: dict) -> dict:
        return {}

    def close_envs(self, setup: Setup) -> None:
        """Closes the collector's envs when the run failed before its collector existed (a
        built collector closes them on shutdown)."""
        if hasattr(setup.env, "close"):
            setup.env.close()

    def close(self, setup: Setup) -> None:
        """Closes what :meth:`setup` opened besides the collector's envs (also when the run
        could not be built)."""


@dataclass
class Run:
    """Everything :func:`build_run` wires together; ``run.trainer.train()`` trains it."""

    cfg: Any
    family: EnvFamily
    variant: Variant
    setup: Setup
    trainer: Any
    collector: Any
    actor: Any
    critic: Any
    encoder: Any
    inverse_model: Any
    collection_policy: Any
    loss: Any
    metrics: MetricsHook | None
    out: Path
    device: torch.device
    resumed_from: int = 0
    lock: Any = None  # the out_dir lock (released when the run is finished or the process ends)
    train_time_s: float = 0.0
    init_frames: int = 0  # frames the init_from weights had seen (0: a fresh start)

    @property
    def env(self):
        return self.setup.env

    @property
    def demos(self):
        return self.setup.demos


def make_inverse_model(
    kind: str | None,
    encoder: torch.nn.Module,
    n_actions: int,
    *,
    d_state: int = 128,
    d: int = 128,
    rank: int = 2,
    mlp_layers: int = 2,
    n_states: int | None = None,
):
    """The variant's inverse model: ``"dual"`` (the paper's low-rank tensor model; with
    ``n_states`` also its forward head), ``"mlp"`` (the MLP baseline) or ``None``."""
    if kind == "dual":
        return DualInverseDynamics(encoder, n_actions, d_state=d_state, d=d, rank=rank, n_states=n_states)
    if kind == "mlp":
        return MLPInverseDynamics(encoder, n_actions, d_state=d_state, hidden=d, num_layers=mlp_layers)
    return None


def _dotted(d: Mapping, name: str, default=None):
    for part in name.split("."):
        if not isinstance(d, Mapping) or part not in d:
            return default
        d = d[part]
    return d


def load_init_weights(
    path: str | Path,
    cfg,
    family: EnvFamily,
    actor: torch.nn.Module,
    critic: torch.nn.Module,
    inverse_model: torch.nn.Module | None = None,
) -> int:
    """Warm start (``init_from``): loads the actor's and critic's weights, and the inverse
    model's where this run and the saved one both have one of the same shape, from a
    ``model.pt`` written by :func:`finish_run` for the same env (``family.init_keys`` must
    agree). The optimiser is not touched. Returns the frames those weights had seen."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"init_from={str(path)!r}: no such file; pass the model.pt of a finished run "
            "(e.g. results/atari/expert_pong_10m/model.pt)"
        )
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # truncated, random bytes, another format
        raise ValueError(
            f"init_from={path} is not a model.pt written by this pipeline ({type(err).__name__}: {err})"
        ) from None
    need = ("actor", "critic", "config")
    if not isinstance(ckpt, dict) or any(k not in ckpt for k in need):
        have = sorted(ckpt) if isinstance(ckpt, dict) else type(ckpt).__name__
        raise ValueError(
            f"init_from={path} is not a model.pt written by this pipeline: it needs {list(need)}, it has {have}"
        )
    saved, now = ckpt["config"], dataclasses.asdict(cfg)
    diff = [k for k in family.init_keys if _dotted(saved, k) != _dotted(now, k)]
    if diff:
        was = ", ".join(f"{k}: {_dotted(saved, k)!r} (saved) vs {_dotted(now, k)!r} (this run)" for k in diff)
        raise ValueError(
            f"init_from={path} was trained with other settings for {diff} ({was}); "
            "warm-start from a run of the same env and networks"
        )
    for name, module in (("actor", actor), ("critic", critic)):
        try:
            module.load_state_dict(ckpt[name])
        except RuntimeError as err:
            raise ValueError(f"init_from={path}: its {name} does not fit this run's ({err})") from None
    saved_idm = ckpt.get("inverse_model")
    if inverse_model is not None and saved_idm is not None:
        try:
            inverse_model.load_state_dict(saved_idm)
        except RuntimeError as err:
            raise ValueError(
                f"init_from={path}: its inverse model does not fit this run's (another variant, rank or "
                f"idm_encoder?) ({err})"
            ) from None
    frames = ckpt.get("total_frames_seen")  # older model.pt files: the frames their run was asked for
    return int(frames if frames is not None else saved.get("total_frames", 0))


def build_run(cfg, family: EnvFamily) -> Run:
    """Builds the envs, networks, losses, collector and TorchRL trainer of one run (hooks
    registered, checkpoint resumed when ``cfg.resume``), without training."""
    cfg.validate()
    device = resolve_device(cfg.device, small_model=family.small_model(cfg))  # networks, learner, demos; envs: CPU
    variant = get_variant(cfg.variant)
    out = Path(cfg.out_dir)
    if cfg.resume:  # a finished run that total_frames does not extend: refused before any file is touched
        check_resume_target(out, cfg.total_frames)
    lock = prepare_out_dir(out, resume=cfg.resume, overwrite=cfg.overwrite)  # held while the run lives
    setup = collector = None
    try:
        torch.manual_seed(cfg.seed)
        setup = family.setup(cfg, variant, device, torch.Generator().manual_seed(cfg.seed))
        nets = family.networks(cfg, variant, setup)
        n_states = setup.n_states if cfg.loss.idm_forward_coeff > 0 else None
        inverse_model = make_inverse_model(
            variant.inverse_model,
            nets.inverse_encoder() if variant.inverse_model else None,
            setup.n_actions,
            d_state=cfg.d_state,
            d=cfg.d,
            rank=cfg.rank,
            mlp_layers=cfg.mlp_layers,
            n_states=n_states,
        )
        loss = make_hybrid_loss(
            variant,
            nets.actor,
            nets.critic,
            inverse_model,
            expert_action_key=EXPERT_ACTION_KEY,
            rl=cfg.rl,
            ppo=dataclasses.asdict(cfg.ppo),
            **cfg.loss.loss_kwargs(),
            **family.loss_extra,
        ).to(device)
        # the loss moves the networks it trains; the collection policy may hold more (Atari's writes the
        # critic's state_value, which a variant without the RL loss never trains)
        for net in (nets.actor, nets.critic, nets.collection_policy):
            if net is not None:
                net.to(device)
        optimizer = cfg.optim.make(param_groups(loss))
        skip = family.frame_skip(setup)
        policy = nets.collection_policy if nets.collection_policy is not None else nets.actor
        if cfg.loss.explore_envs > 0:  # some env slots act at random, for the inverse model's data
            policy = ExplorerSlots(policy, setup.n_actions, cfg.loss.explore_envs)
        collector = family.collector(cfg, setup, policy, device, -(-cfg.total_frames // skip))
        logger = None
        if cfg.logger.backend != "none":
            logger = get_logger(
                cfg.logger.backend, logger_name=str(out / "logs"), experiment_name=family.experiment_name(cfg)
            )
        frames_per_batch = cfg.frames_per_batch * skip
        trainer = make_trainer(
            collector=collector,
            loss=loss,
            optimizer=optimizer,
            total_frames=cfg.total_frames,
            clip_norm=cfg.optim.max_grad_norm,
            logger=logger,
            progress_bar=cfg.logger.progress_bar,
            save_trainer_file=out / "checkpoint" if cfg.logger.checkpoint else None,
            save_trainer_interval=max(cfg.total_frames // family.checkpoints_per_run, frames_per_batch),
            clip=cfg.optim.clip,
            frame_skip=skip,
            bc_updates=cfg.loss.bc_updates,
            idm_updates=cfg.loss.idm_updates,
            optim_steps_per_batch=cfg.optim_steps_per_batch,
        )
        run = Run(
            cfg,
            family,
            variant,
            setup,
            trainer,
            collector,
            nets.actor,
            nets.critic,
            nets.encoder,
            inverse_model,
            policy,
            loss,
            None,
            out,
            device,
            0,
            lock,
        )
        if cfg.init_from:
            run.init_frames = load_init_weights(cfg.init_from, cfg, family, nets.actor, nets.critic, inverse_model)
        warmup = cfg.optim.warmup_frames
        if warmup is None:  # auto
            warmup = WARMUP_UPDATES * frames_per_batch if cfg.init_from else 0
        if warmup > 0:
            LRWarmupHook(optimizer, warmup).register(trainer)
        if family.uses_workers(cfg):
            BatchToDeviceHook(device).register(trainer)  # the workers store their batches on the CPU
        if cfg.rl == "ppo" and loss.rl_loss is not None:  # before the expert batches: they pair with each minibatch
            MinibatchHook(loss.rl_loss.value_estimator, cfg.ppo.minibatches).register(trainer)
        family.register_hooks(run)
        if family.uses_workers(cfg):  # the workers' policy copies get the learner's weights after every batch
            UpdateWeights(
                collector, update_weights_interval=1, policy_weights_getter=worker_weights_getter(policy)
            ).register(trainer)
        if variant.bc is not None:
            expert_buffer = attach_demonstrations(
                trainer,
                loss,
                setup.demos,
                sampler=family.sampler(cfg, setup),
                batch_size=cfg.demo.batch_size,
                **cfg.loss.bc_schedule_kwargs(),
                include_expert_actions=variant.bc == "true",
                device=device,
            )
            # loss.bc_updates: the extra BC-only updates draw their expert batches from the same buffer
            trainer.optimization_stepper.expert_batches = lambda: expert_buffer.sample(cfg.demo.batch_size)
        run.metrics = MetricsHook(
            out / "metrics.csv",
            cfg.logger.log_every_frames,
            family.evaluator(run),
            pbar_keys=family.pbar_keys,
            return_key=family.return_key,
        )
        run.metrics.register(trainer)
        family.register_late_hooks(run)
        settings = dataclasses.asdict(cfg)
        if cfg.resume:
            run.resumed_from = resume_trainer(
                trainer,
                out,
                settings,
                family.resume_keys,
                family.resume_ignore,
                defaults=dataclasses.asdict(type(cfg)()),
            )
        (out / "config.json").write_text(json.dumps(settings, indent=2))
    except BaseException:  # a run that could not be built closes what it opened and does not keep out_dir
        try:
            if collector is not None:
                collector.shutdown()
            elif setup is not None:
                family.close_envs(setup)
            if setup is not None:
                family.close(setup)
        finally:
            lock.close()
        raise
    return run


def finish_run(run: Run) -> dict[str, Any]:
    """After ``run.trainer.train()``: the family's final evaluation, then ``summary.json``,
    ``model.pt`` and ``learning_curve.png`` in ``out_dir``; closes the run. Returns the summary."""
    cfg, trainer = run.cfg, run.trainer
    try:
        results, model_extra = run.family.finish(run)
        train_time = max(run.train_time_s, 1e-9)
        summary = {
            **results.pop("head", {}),
            "variant": cfg.variant,
            "seed": cfg.seed,
            "frames": int(trainer.collected_frames),
            **results,
            "resumed_from_frames": run.resumed_from,
            # the weights' whole history: init_from's frames, then this run's
            "init_from": cfg.init_from or None,
            "total_frames_seen": run.init_frames + int(trainer.collected_frames),
            "train_time_s": round(train_time, 2),  # this piece only, when resumed
            "frames_per_s": round((trainer.collected_frames - run.resumed_from) / train_time, 1),
            "config": dataclasses.asdict(cfg),
        }
        (run.out / "summary.json").write_text(json.dumps(summary, indent=2))
        torch.save(
            {
                "actor": run.actor.state_dict(),
                "critic": run.critic.state_dict(),
                "inverse_model": None if run.inverse_model is None else run.inverse_model.state_dict(),
                **model_extra,
                "config": dataclasses.asdict(cfg),
                "total_frames_seen": run.init_frames + int(trainer.collected_frames),
            },
            run.out / "model.pt",
        )
        plot_learning_curve(
            run.metrics.rows,
            run.out / "learning_curve.png",
            title=run.family.title(cfg),
            **run.family.plot_kwargs(run, summary),
        )
    finally:
        close_run(run)
    return summary


def close_run(run: Run) -> None:
    """Shuts the collector (and its workers) down, closes the family's other envs and
    releases ``out_dir``."""
    try:
        run.collector.shutdown()
        run.family.close(run.setup)
    finally:
        if run.lock is not None:
            run.lock.close()


def train_run(cfg, family: EnvFamily) -> dict[str, Any]:
    """Builds, trains and finishes one run; returns its summary (also in ``summary.json``)."""
    run = build_run(cfg, family)
    try:
        t0 = time.perf_counter()
        run.trainer.train()
        run.train_time_s = time.perf_counter() - t0
    except BaseException:
        close_run(run)
        raise
    return finish_run(run)


def finite(x) -> float | None:
    """``x`` as a float, ``None`` for missing or NaN (JSON has no NaN)."""
    return None if x is None or not math.isfinite(x) else float(x)
