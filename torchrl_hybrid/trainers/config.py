"""The settings every env family shares, as Hydra structured-config schemas: the losses
(:class:`LossConfig`), the optimiser, PPO, the demos, the logger, and the run itself
(:class:`RunConfig`, which each family's config extends). Each field is documented where
it is declared; each group's ``validate()`` refuses a bad value by name before anything
trains."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import torch
from torchrl.trainers.algorithms.configs.utils import RMSpropConfig

from torchrl_hybrid.utils.config import MAX_FRAMES, MAX_SEED, MAX_THREADS, check_float, check_int, check_types, require
from torchrl_hybrid.variants import RL_BASES, get_variant

__all__ = [
    "BC_LABELS",
    "CLIPS",
    "LOGGERS",
    "DemoConfig",
    "LoggerConfig",
    "LossConfig",
    "OptimConfig",
    "PPOConfig",
    "RunConfig",
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
        require(
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
        require(self.bc_labels in BC_LABELS, f"loss.bc_labels must be one of {BC_LABELS}, got {self.bc_labels!r}")
        check_float("loss.bc_confidence", self.bc_confidence, 0.0, 1.0, hi_open=True)
        check_float("loss.bc_ready_accuracy", self.bc_ready_accuracy, 0.0, 1.0)
        check_float("loss.bc_prior_floor", self.bc_prior_floor, 0.0, 1.0)
        check_int("loss.bc_start_frames", self.bc_start_frames, 0, MAX_FRAMES)
        check_int("loss.bc_anneal_frames", self.bc_anneal_frames, 0, MAX_FRAMES)
        for name in ("bc_updates", "idm_updates", "explore_envs"):
            check_int(f"loss.{name}", getattr(self, name), 0)

    def loss_kwargs(self) -> dict[str, Any]:
        """The keyword arguments of :func:`~torchrl_hybrid.variants.make_hybrid_loss`."""
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

    def bc_schedule_kwargs(self) -> dict[str, Any]:
        """The keyword arguments of :func:`~torchrl_hybrid.trainers.trainer.attach_demonstrations`
        that say when the BC term is on and how strong: with :meth:`loss_kwargs` the one path
        from the ``loss.bc_*`` settings to the run."""
        return {k: getattr(self, k) for k in ("bc_coeff", "bc_start_frames", "bc_ready_accuracy", "bc_anneal_frames")}


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
        """The optimiser over ``params`` (e.g. :func:`~torchrl_hybrid.variants.param_groups`)."""
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
        require(self.clip in CLIPS, f"optim.clip must be one of {CLIPS}, got {self.clip!r}")
        require(
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
            require(
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
        require(self.backend in LOGGERS, f"logger.backend must be one of {LOGGERS}, got {self.backend!r}")
        package = LOGGER_PACKAGES.get(self.backend)
        require(
            package is None or _has_package(package),
            f"logger.backend={self.backend} needs the {package} package, which is not installed: "
            f"pip install -e '.[{package}]' (or logger.backend=csv)",
        )
        check_int("logger.log_every_frames", self.log_every_frames, 1, MAX_FRAMES)


@dataclass
class RunConfig:
    """The settings every run has, whatever its env; each env family's config
    (``GymConfig``, ``AtariConfig``) extends it and changes the defaults its env needs."""

    variant: str = "hybrid_dual"  # the agent (torchrl_hybrid/variants.py: VARIANTS); hybrid_dual is the paper's
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
        require(
            not (self.resume and self.overwrite), "resume=true and overwrite=true contradict each other: choose one"
        )
        self.demo.validate(self.variant if variant.bc is not None else None)
        self.loss.validate()
        self.optim.validate()
        self.logger.validate()
        self.ppo.validate()
        self.validate_rl()

    def validate_rl(self) -> None:
        """The RL base and its combinations with the other groups (validate_run calls it)."""
        require(self.rl in RL_BASES, f"rl must be one of {RL_BASES}, got {self.rl!r}")
        if self.rl == "ppo":
            require(
                self.loss.gamma * self.ppo.gae_lambda >= MIN_DISCOUNT,
                f"loss.gamma * ppo.gae_lambda = {self.loss.gamma * self.ppo.gae_lambda:g} must be >= {MIN_DISCOUNT:g}: "
                "TorchRL's GAE fails below 1e-7; raise ppo.gae_lambda",
            )
            require(
                self.frames_per_batch % self.ppo.minibatches == 0,
                f"ppo.minibatches={self.ppo.minibatches} must divide a batch of {self.frames_per_batch} transitions "
                "(env.num_envs * loss.n_steps)",
            )

    @property
    def optim_steps_per_batch(self) -> int:
        return self.ppo.epochs * self.ppo.minibatches if self.rl == "ppo" else 1


def _has_package(name: str) -> bool:
    """Whether ``name`` can be imported (without importing it)."""
    import importlib.util

    return importlib.util.find_spec(name) is not None
