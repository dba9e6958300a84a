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
:class:`~torchrl_hybrid.trainers.taxi.GymFamily`, Atari's is
:class:`~torchrl_hybrid.trainers.atari.AtariFamily`; ``train_taxi(cfg)`` and
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
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import torch
from torchrl.record.loggers import get_logger
from torchrl.trainers import UpdateWeights
from torchrl.trainers.algorithms.configs.utils import RMSpropConfig

from torchrl_hybrid.collectors.workers import BatchToDeviceHook, worker_weights_getter
from torchrl_hybrid.data import EXPERT_ACTION_KEY
from torchrl_hybrid.modules import DualInverseDynamics, ExplorerSlots, MLPInverseDynamics
from torchrl_hybrid.trainers.hooks import LRWarmupHook, MetricsHook, MinibatchHook
from torchrl_hybrid.trainers.hybrid import (
    Variant,
    attach_demonstrations,
    get_variant,
    make_hybrid_loss,
    make_trainer,
    param_groups,
    resume_trainer,
)
from torchrl_hybrid.utils.config import MAX_FRAMES, MAX_SEED, MAX_THREADS, check_float, check_int, check_types
from torchrl_hybrid.utils.device import resolve_device
from torchrl_hybrid.utils.files import check_resume_target, prepare_out_dir
from torchrl_hybrid.utils.plotting import plot_learning_curve

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

LOGGERS = ("csv", "tensorboard", "wandb", "none")
LOGGER_PACKAGES = {"tensorboard": "tensorboard", "wandb": "wandb"}  # the package (= pyproject extra) each one needs
BC_LABELS = ("argmax", "soft")
CLIPS = ("global", "per_group", "per_term")
# the smallest discount (loss.gamma, and gamma * ppo.gae_lambda for GAE) TorchRL's return estimators take: they
# keep the powers of the discount above 1e-7, and find none below it (an IndexError deep in the first update)
MIN_DISCOUNT = 1e-6
WARMUP_UPDATES = 100  # optim.warmup_frames=None with init_from: the lr warm-up lasts this many updates


@dataclass
class LossConfig:
    """The loss settings of every env; the defaults are the paper's Taxi agent (where the paper
    is silent, the authors' Taxi code). Atari's config overrides those the paper sets otherwise
    (``AtariLossConfig``)."""

    n_steps: int = 2  # paper: 2-step A2C on Taxi (rollout length; TD(1) return bootstrapped at its end)
    gamma: float = 0.99  # authors' code
    critic_coeff: float = 0.2  # authors' code: value loss weight (L2)
    entropy_coeff: float = 0.5  # authors' code: entropy bonus weight (the BC variants keep it too)
    idm_action_coeff: float = 2.0  # authors' code: weight of -log P_i(a|s,s')
    idm_embedding_coeff: float = 0.1  # authors' code: weight of the L1 embedding terms (averaged over dims: OURS)
    idm_forward_coeff: float = 0.0  # authors' code: 0 (the paper trains L_act); > 0 adds -log P_f(s'|s,a)
    # (discrete states only)
    bc_coeff: float = 2.0  # authors' README runs: weight of the BC term
    bc_start_frames: int = 0  # switch the BC term on after this many frames (paper's Atari: 100,000)
    # Label handling (options beyond the paper; the paper's agent is the default):
    bc_labels: str = "argmax"  # argmax = clone argmax_a P_i (the paper) | soft = cross-entropy to P_i, so
    # look-alike actions share probability instead of one being erased
    bc_confidence: float = 0.0  # clone only expert pairs whose max_a P_i >= this (0: every pair)
    bc_entropy_floor: float = 0.0  # add bc_coeff * relu(floor - H(pi)) on expert states (0: off)
    # > 0: labels corrected for the agent's own policy, P_i(a|s,s') / max(pi(a|s), floor) renormalised: the
    # inverse model learns the agent's policy as its prior, so its labels echo the agent (OURS; 0 = the paper)
    bc_prior_floor: float = 0.0
    # > 0: BC switches on once the inverse model's running accuracy on the agent's own transitions (each
    # batch measured before it is trained on; no expert labels) reaches this, and not before bc_start_frames
    bc_ready_accuracy: float = 0.0
    # > 0: after switching on (at bc_start_frames, or when ready with bc_ready_accuracy), the BC weight falls
    # linearly from bc_coeff to 0 over this many frames (OURS: annealing, so that the RL signal takes over from
    # labels that are only partly right; 0 = constant, the paper)
    bc_anneal_frames: int = 0
    # The objective's balance (OURS; 0 = the paper's one update of every term per collected batch):
    # after that update, this many more updates of the BC term alone (each on a fresh expert batch) ...
    bc_updates: int = 0
    # ... and of the inverse model's loss alone (on the same agent batch); the RL loss is never repeated
    idm_updates: int = 0
    # > 0: this many env slots act uniformly at random (ExplorerSlots); their transitions train the inverse
    # model, so its labels are not the agent's own favourite action, and are kept out of the RL loss (OURS)
    explore_envs: int = 0

    def validate(self) -> None:
        check_types(self, "loss.")
        check_int("loss.n_steps", self.n_steps, 1)
        check_float("loss.gamma", self.gamma, 0.0, 1.0)
        _need(
            self.gamma >= MIN_DISCOUNT,
            f"loss.gamma={self.gamma} must be >= {MIN_DISCOUNT:g}: TorchRL's return "
            "estimators fail on discounts below 1e-7 (for a short-sighted agent use e.g. 0.01)",
        )
        # loss weights: a negative one turns its term into one to maximise; above MAX_COEFF float32 losses
        # and their squared gradients overflow
        for name in (
            "critic_coeff",
            "entropy_coeff",
            "idm_action_coeff",
            "idm_embedding_coeff",
            "idm_forward_coeff",
            "bc_coeff",
            "bc_entropy_floor",
        ):
            check_float(f"loss.{name}", getattr(self, name), 0.0)
        _need(self.bc_labels in BC_LABELS, f"loss.bc_labels must be one of {BC_LABELS}, got {self.bc_labels!r}")
        check_float("loss.bc_confidence", self.bc_confidence, 0.0, 1.0, hi_open=True)
        check_float("loss.bc_ready_accuracy", self.bc_ready_accuracy, 0.0, 1.0)
        check_float("loss.bc_prior_floor", self.bc_prior_floor, 0.0, 1.0)
        check_int("loss.bc_start_frames", self.bc_start_frames, 0, MAX_FRAMES)
        check_int("loss.bc_anneal_frames", self.bc_anneal_frames, 0, MAX_FRAMES)
        for name in ("bc_updates", "idm_updates", "explore_envs"):
            check_int(f"loss.{name}", getattr(self, name), 0)

    def loss_kwargs(self) -> dict[str, Any]:
        """The keyword arguments of :func:`~torchrl_hybrid.trainers.hybrid.make_hybrid_loss`."""
        return {
            k: getattr(self, k)
            for k in (
                "gamma",
                "critic_coeff",
                "entropy_coeff",
                "idm_action_coeff",
                "idm_embedding_coeff",
                "idm_forward_coeff",
                "bc_coeff",
                "bc_labels",
                "bc_confidence",
                "bc_entropy_floor",
                "bc_prior_floor",
            )
        }


@dataclass
class OptimConfig(RMSpropConfig):
    """RMSprop over the de-duplicated parameters (policy, inverse model), gradient clipping.
    TorchRL's own ``RMSpropConfig`` (torchrl.trainers.algorithms.configs), every
    ``torch.optim.RMSprop`` argument, with the authors' defaults, plus the clipping settings."""

    lr: float = 1e-3  # RMSprop, authors' code
    eps: float = 1e-5
    alpha: float = 0.99
    max_grad_norm: float = 0.5  # gradient-norm clip, authors' code
    # global = one clip over all parameters (TorchRL's default stepper, the authors' code);
    # per_group = policy and inverse model clipped separately (OURS, optional);
    # per_term = the RL, inverse-model and BC losses each differentiated and clipped on their own, then
    # summed, so that a large RL gradient does not scale the BC term down with it (OURS, optional)
    clip: str = "global"
    # lr rises linearly from 0 over this many frames (LRWarmupHook); None = auto: 100 updates' frames with
    # init_from (a fresh RMSprop's first steps on trained weights are up to 10x lr), else 0 (the authors': none)
    warmup_frames: int | None = None

    def make(self, params) -> torch.optim.Optimizer:
        """The optimiser over ``params`` (e.g. :func:`~torchrl_hybrid.trainers.hybrid.param_groups`)."""
        kwargs = {
            f.name: getattr(self, f.name) for f in dataclasses.fields(RMSpropConfig) if not f.name.startswith("_")
        }
        return torch.optim.RMSprop(params, **kwargs)

    def validate(self) -> None:
        check_types(self, "optim.")
        # RMSprop moves each weight by about lr per update: above 1 a few updates throw the weights past
        # any useful scale (and in float32 soon to inf/NaN)
        check_float("optim.lr", self.lr, 0.0, 1.0, lo_open=True)
        check_float("optim.eps", self.eps, 0.0, lo_open=True)  # 0: a weight with no gradient yet divides 0 by 0
        check_float("optim.alpha", self.alpha, 0.0, 1.0, hi_open=True)  # 1: the squared-gradient average never moves
        check_float("optim.momentum", self.momentum, 0.0, 1.0, hi_open=True)
        check_float("optim.weight_decay", self.weight_decay, 0.0)
        check_float("optim.max_grad_norm", self.max_grad_norm, 0.0, lo_open=True)  # 0 clips every step to nothing
        if self.warmup_frames is not None:
            check_int("optim.warmup_frames", self.warmup_frames, 0, MAX_FRAMES)
        _need(self.clip in CLIPS, f"optim.clip must be one of {CLIPS}, got {self.clip!r}")
        _need(
            self._target_ == "torch.optim.RMSprop",
            f"optim._target_={self._target_!r}: the agent's optimiser is torch.optim.RMSprop (the paper's); "
            "for another one build the run with build_run and replace run.trainer.optimizer",
        )


@dataclass
class PPOConfig:
    """``rl=ppo``: TorchRL's ``ClipPPOLoss`` with GAE, ``epochs`` passes over each collected batch
    in ``minibatches`` minibatches (OURS: the paper's RL base is A2C; these are the usual PPO values)."""

    epochs: int = 4
    minibatches: int = 4  # must divide env.num_envs * loss.n_steps
    clip_epsilon: float = 0.2
    gae_lambda: float = 0.95
    normalize_advantage: bool = True

    def validate(self) -> None:
        check_types(self, "ppo.")
        check_int("ppo.epochs", self.epochs, 1)
        check_int("ppo.minibatches", self.minibatches, 1)
        check_float("ppo.clip_epsilon", self.clip_epsilon, 0.0, 1.0, lo_open=True, hi_open=True)
        check_float("ppo.gae_lambda", self.gae_lambda, 0.0, 1.0)


@dataclass
class DemoConfig:
    """Where the expert's state pairs come from and how the BC term samples them; each env
    family adds its own demo settings."""

    path: str | None = None  # a folder of recorded demos (save_demos / recipes/atari_demos.py)
    batch_size: int = 32  # expert pairs per optimisation step
    curriculum_k0: int = 10  # curriculum rho: first k steps of each trajectory at the start ...
    curriculum_frames_per_step: int = 8000  # ... one step more every this many frames

    def validate(self, variant: str | None = None) -> None:
        """``variant``: the run's, when it clones the expert from these demos (its BC batches
        must hold at least one pair)."""
        check_types(self, "demo.")
        check_int("demo.batch_size", self.batch_size, 0)
        if variant is not None:
            _need(
                self.batch_size >= 1,
                f"demo.batch_size={self.batch_size}: variant {variant} clones the expert from "
                "batches of this many demo pairs, so it must be >= 1 (variant=a2c trains without demos)",
            )
        check_int("demo.curriculum_k0", self.curriculum_k0, 1)
        check_int("demo.curriculum_frames_per_step", self.curriculum_frames_per_step, 1, MAX_FRAMES)


@dataclass
class LoggerConfig:
    """The learning curve, TorchRL's logger, progress bar and checkpoints; each env family
    adds its evaluation settings."""

    # csv | tensorboard | wandb | none (metrics.csv is always written); tensorboard and wandb need their
    # package: pip install -e '.[tensorboard]' or '.[wandb]'
    backend: str = "csv"
    log_every_frames: int = 2000  # frames between learning-curve rows
    progress_bar: bool = True
    checkpoint: bool = True  # TorchRL trainer checkpoints in out_dir/checkpoint (what resume=true reads)

    def validate(self) -> None:
        check_types(self, "logger.")
        _need(self.backend in LOGGERS, f"logger.backend must be one of {LOGGERS}, got {self.backend!r}")
        package = LOGGER_PACKAGES.get(self.backend)
        _need(
            package is None or _has_package(package),
            f"logger.backend={self.backend} needs the {package} package, which is not installed: "
            f"pip install -e '.[{package}]' (or logger.backend=csv)",
        )
        check_int("logger.log_every_frames", self.log_every_frames, 1, MAX_FRAMES)


@dataclass
class RunConfig:
    """The settings every run has, whatever its env; each env family's config
    (``TaxiConfig``, ``AtariConfig``) extends it and changes the defaults its env needs."""

    variant: str = "hybrid_dual"  # the agent (trainers/hybrid.py: VARIANTS); hybrid_dual is the paper's
    # the RL loss of the variants that have one: a2c (the paper's) | ppo (ClipPPOLoss + GAE, the ppo settings)
    rl: str = "a2c"
    seed: int = 0
    total_frames: int = 80_000  # frames to train (summed over the parallel envs)
    rank: int = 2  # rank R of the dual tensor model
    d_state: int = 128  # d_s, size of the state embedding h_s (paper: 128)
    d: int = 128  # d, size of h_a and h_ds (paper: 128); also the MLP baseline's hidden width
    mlp_layers: int = 2  # hidden layers of the MLP inverse model (paper: 2)
    # where metrics.csv, summary.json, learning_curve.png, model.pt and checkpoint/ go; a folder that
    # holds a run is refused unless resume or overwrite (the recipes default to a fresh timestamped one)
    out_dir: str = "outputs/run"
    threads: int = 1  # torch CPU threads, set by the recipes (utils/process.py), not by the library (0: torch's)
    # where the networks, the learner and the demos live: auto (CUDA when available) | cpu | cuda | cuda:N;
    # the envs stay on the CPU. A checkpoint written on one device resumes or loads on another.
    device: str = "auto"
    # continue the run in out_dir from its checkpoint/ (the settings must agree with its config.json;
    # raise total_frames to train a finished run longer)
    resume: bool = False
    # warm start: the actor's and critic's weights (and the inverse model's, where both runs have one) from
    # the model.pt of an earlier run of the same env, e.g. train an expert longer:
    # init_from=results/atari/expert_pong_10m/model.pt. The optimiser starts fresh, frames count from 0
    # (summary.json adds the frames the weights had already seen); a checkpoint that resume=true finds wins
    init_from: str = ""
    # replace the run in out_dir (summary, model, curve, checkpoint); nothing else there is touched
    overwrite: bool = False
    demo: DemoConfig = field(default_factory=DemoConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)

    def validate_run(self) -> None:
        """The settings every run has and the shared groups (demo, loss, optim, logger, ppo, the
        RL base); each family's validate calls it after its own variant check and adds its groups."""
        check_types(self, recurse=False)
        variant = get_variant(self.variant)
        check_int("seed", self.seed, 0, MAX_SEED)
        check_int("total_frames", self.total_frames, 1, MAX_FRAMES)
        for name in ("rank", "d_state", "d", "mlp_layers"):
            check_int(name, getattr(self, name), 1)
        check_int("threads", self.threads, 0, MAX_THREADS)
        _need(not (self.resume and self.overwrite), "resume=true and overwrite=true contradict each other: choose one")
        self.demo.validate(self.variant if variant.bc is not None else None)
        self.loss.validate()
        self.optim.validate()
        self.logger.validate()
        self.ppo.validate()
        self.validate_rl()

    def validate_rl(self) -> None:
        """The RL base and its combinations with the other groups (validate_run calls it)."""
        from torchrl_hybrid.trainers.hybrid import RL_BASES

        _need(self.rl in RL_BASES, f"rl must be one of {RL_BASES}, got {self.rl!r}")
        if self.rl == "ppo":
            _need(
                self.loss.gamma * self.ppo.gae_lambda >= MIN_DISCOUNT,
                f"loss.gamma * ppo.gae_lambda = {self.loss.gamma * self.ppo.gae_lambda:g} must be >= {MIN_DISCOUNT:g}: "
                "TorchRL's GAE fails below 1e-7; raise ppo.gae_lambda",
            )
            _need(
                self.frames_per_batch % self.ppo.minibatches == 0,
                f"ppo.minibatches={self.ppo.minibatches} must divide a batch of {self.frames_per_batch} transitions "
                "(env.num_envs * loss.n_steps)",
            )

    @property
    def optim_steps_per_batch(self) -> int:
        return self.ppo.epochs * self.ppo.minibatches if self.rl == "ppo" else 1


def _need(ok: bool, msg: str) -> None:
    if not ok:
        raise ValueError(msg)


def _has_package(name: str) -> bool:
    """Whether ``name`` can be imported (without importing it)."""
    import importlib.util

    return importlib.util.find_spec(name) is not None


@dataclass
class Setup:
    """What :meth:`EnvFamily.setup` builds: the training env (or the collector's envs),
    the action count, the demos (``None`` for plain A2C) and whatever else the family
    keeps for its later steps (``extra``)."""

    env: Any
    n_actions: int
    demos: Any = None
    extra: dict = field(default_factory=dict)


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
        n_states = setup.extra.get("n_states") if cfg.loss.idm_forward_coeff > 0 else None
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
            lc = cfg.loss
            expert_buffer = attach_demonstrations(
                trainer,
                loss,
                setup.demos,
                sampler=family.sampler(cfg, setup),
                batch_size=cfg.demo.batch_size,
                bc_coeff=lc.bc_coeff,
                bc_start_frames=lc.bc_start_frames,
                bc_ready_accuracy=lc.bc_ready_accuracy,
                bc_anneal_frames=lc.bc_anneal_frames,
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
