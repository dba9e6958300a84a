"""The Atari pipeline: its configuration and :class:`AtariFamily`, its part of the one
run assembly (:mod:`torchrl_hybrid.trainers.run`).

The recipes ``recipes/atari_expert.py``, ``recipes/atari_demos.py`` and
``recipes/atari.py`` are Hydra front-ends over :func:`train_atari` and
:func:`~torchrl_hybrid.experts.record_demos`; tests call these directly. Same
losses, hooks and trainer as Taxi; only the networks (a shared CNN), the env and the
demo source differ.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import torch
from torchrl.collectors import Collector
from torchrl.envs import RewardSum, TransformedEnv

from torchrl_hybrid.collectors import WORKER_KINDS, AtariCollector, make_worker_collector
from torchrl_hybrid.collectors.workers import worker_devices
from torchrl_hybrid.data import EXPERT_ACTION_KEY, CurriculumSampler, check_trajectories, load_demos
from torchrl_hybrid.envs.atari import AtariEnv
from torchrl_hybrid.experts import load_expert, record_demos
from torchrl_hybrid.modules import AtariEncoder, make_atari_actor_critic
from torchrl_hybrid.modules.atari import orthogonal_init_
from torchrl_hybrid.trainers.config import DemoConfig, LoggerConfig, LossConfig, OptimConfig, RunConfig
from torchrl_hybrid.trainers.evaluation import evaluate_atari, inverse_model_accuracy
from torchrl_hybrid.trainers.hooks import NextStateValueHook, RandomStateHook
from torchrl_hybrid.trainers.run import (  # what Atari's settings extend
    EnvFamily,
    Networks,
    Run,
    Setup,
    build_run,
    finite,
    train_run,
)
from torchrl_hybrid.utils.config import (
    MAX_FRAMES,
    MAX_THREADS,
    check_float,
    check_int,
    check_types,
    dataclass_from_dict,
)
from torchrl_hybrid.utils.device import resolve_device
from torchrl_hybrid.utils.metrics import IDM_ACCURACY_AGENT, IDM_ACCURACY_EXPERT
from torchrl_hybrid.variants import get_variant

# evaluate_atari, record_demos and load_expert live with evaluation and the experts; exported here as before
__all__ = [
    "AtariConfig",
    "AtariFamily",
    "AtariRun",
    "atari_config",
    "build_atari",
    "train_atari",
    "evaluate_atari",
    "record_demos",
    "load_expert",
]

ATARI_VARIANTS = ("hybrid_dual", "hybrid_mlp", "bc_dual", "a2c", "hybrid_true")  # hybrid_true: the oracle diagnostic
INITS = ("orthogonal", "default")  # AtariConfig.init


# The settings below are the Hydra schema of recipes/config/atari.yaml (torchrl_hybrid/configs.py):
# each default is written here once. Where the paper is silent we use the A2C defaults of the
# authors' base code (ikostrikov's pytorch-a2c-ppo-acktr); choices of ours are marked OURS.


@dataclass
class AtariEnvConfig:
    game: str = "Pong"  # any ALE game; the paper's: Alien BeamRider Breakout MsPacman Pong Qbert Seaquest SpaceInvaders
    num_envs: int = 16  # paper: 16 parallel environments; any number works (32, 64 on a GPU machine)
    num_threads: int = 2  # ALE worker threads
    noop_max: int = 30  # standard: up to 30 no-ops at episode start
    max_episode_frames: int = 108_000

    def validate(self) -> None:
        check_types(self, "env.")
        check_int("env.num_envs", self.num_envs, 1)
        check_int("env.num_threads", self.num_threads, 1, MAX_THREADS)
        check_int("env.noop_max", self.noop_max, 0)
        check_int("env.max_episode_frames", self.max_episode_frames, 1, MAX_FRAMES)


@dataclass
class AtariCollectorConfig:
    # atari: AtariCollector (torchrl_hybrid/collectors/atari.py), the same batches as TorchRL's generic
    #        Collector (tested equal) without its per-step TensorDict plumbing;
    # torchrl: TorchRL's Collector over AtariEnv (the reference path);
    # multi_sync: TorchRL's MultiSyncCollector, the games split between `workers` processes;
    # ray: TorchRL's RayCollector, `workers` Ray actors (pip install -e '.[ray]'); both push the
    #      learner's weights to the workers after every batch (synchronous A2C)
    backend: str = "atari"
    workers: int = 2  # multi_sync / ray: must divide env.num_envs
    address: str | None = None  # ray: the cluster to join (e.g. auto); None starts a local one
    # ray: the share of a GPU each actor asks for, to run its policy there; 0 = the workers run their policy
    # on the CPU (multi_sync workers always do) and each batch is moved to the learner's device
    worker_gpus: float = 0.0
    # atari backend: split the games into this many ale-py vector envs stepped as a pipeline, so that
    # the policy runs on one group's frames while another group's games step. Still synchronous A2C
    # (every action from the current policy on the current frames); pays off where the policy runs
    # on a GPU; on a 2-core CPU machine 1 is faster (benchmarks/atari_throughput.py --all).
    env_groups: int = 1
    # atari backend: the encoder pass made during collection (with autograd on) is handed to the
    # learner, which then does not encode the batch's observations again (same weights, same
    # frames: equal loss and gradients, tested)
    keep_features: bool = True

    def validate(self) -> None:
        check_types(self, "collector.")
        if self.backend not in ("atari", "torchrl", *WORKER_KINDS):
            raise ValueError(f"collector.backend={self.backend!r}: choose atari, torchrl, " + " or ".join(WORKER_KINDS))
        check_int("collector.workers", self.workers, 1)
        check_float("collector.worker_gpus", self.worker_gpus, 0.0, cap=1024)
        worker_devices(self.backend, self.worker_gpus)  # worker_gpus: Ray only
        check_int("collector.env_groups", self.env_groups, 1)
        if self.env_groups > 1 and self.backend != "atari":
            raise ValueError("collector.env_groups > 1 needs collector.backend=atari")


@dataclass
class AtariDemoConfig(DemoConfig):
    """demo.path: the folder written by recipes/atari_demos.py (needed by every variant but a2c).
    The curriculum counts game frames."""

    curriculum: bool = True  # paper: sample only the first K steps of each trajectory (false: uniform)


@dataclass
class AtariLossConfig(LossConfig):
    """:class:`~torchrl_hybrid.trainers.run.LossConfig` with the Atari settings."""

    n_steps: int = 5  # A2C rollout length (base code default)
    critic_coeff: float = 0.5  # base code default
    entropy_coeff: float = 0.01  # base code default
    idm_action_coeff: float = 1.0  # OURS
    # OURS: 0 on Atari. With the L1 embedding terms of the authors' Taxi code (0.1) the dual model never
    # leaves chance level on Atari: the L1 terms shrink h_a and h_ds towards their trivial minimum (0)
    # faster than the weak early action signal grows them (benchmarks/atari_idm_learning.py: Breakout,
    # 128k frames, loss stays at ln 4 with 0.1, reaches 0.8 / 57 % accuracy by 64k frames with 0).
    idm_embedding_coeff: float = 0.0
    bc_coeff: float = 1.0  # OURS
    bc_start_frames: int = 100_000  # paper: inferred actions used only after 100,000 (game) frames


@dataclass
class AtariOptimConfig(OptimConfig):
    lr: float = 7e-4  # RMSprop, base code default


@dataclass
class AtariLoggerConfig(LoggerConfig):
    log_every_frames: int = 40_000  # game frames between learning-curve rows
    accuracy_pairs: int = 512  # demo pairs of the inverse model's accuracy column (idm_accuracy_expert); 0: off
    eval_episodes: int = 0  # whole episodes the final policy plays (sampling); stored in summary.json and model.pt

    def validate(self) -> None:
        super().validate()
        check_int("logger.accuracy_pairs", self.accuracy_pairs, 0)
        check_int("logger.eval_episodes", self.eval_episodes, 0)


@dataclass
class AtariConfig(RunConfig):
    """Every setting of an Atari run, with its default; the Hydra schema of
    ``recipes/config/atari.yaml``. The settings every run has (variant, seed, sizes, out_dir,
    device, resume, ...) are in :class:`~torchrl_hybrid.trainers.run.RunConfig`; variants here:
    hybrid_dual | hybrid_mlp | bc_dual | a2c. The games always run on the CPU (ale-py); their
    frames reach the GPU once per step, as uint8."""

    total_frames: int = 2_000_000  # game frames summed over the envs (4 per agent step), as the paper counts
    rank: int = 8  # paper: rank 8 for Atari (d_state: the paper's 512 -> 128 linear)
    out_dir: str = "outputs/atari"
    threads: int = 2
    # orthogonal = the A2C init of the authors' base code and of SB3 (gain sqrt 2, policy head 0.01);
    # default = PyTorch's layer defaults
    init: str = "orthogonal"
    # torch.compile the CNN (collection and learner): off | default | reduce-overhead (CUDA graphs on a
    # GPU) | max-autotune. Same numbers as off (tested); about as fast as off on a 2-core CPU
    # (benchmarks/atari_compile.py), not measured on a GPU yet
    compile: str = "off"
    # shared = the paper: the inverse model reads the actor's and critic's CNN, so its loss trains
    # that CNN too; own = OURS: the inverse model has a CNN of its own (same architecture and init),
    # so its gradient does not mix with A2C's in the policy's CNN (the hybrids' gradient norm is
    # several times A2C's: benchmarks/atari_grad_norms.py). Costs one more CNN pass per update.
    idm_encoder: str = "shared"
    env: AtariEnvConfig = field(default_factory=AtariEnvConfig)
    collector: AtariCollectorConfig = field(default_factory=AtariCollectorConfig)
    demo: AtariDemoConfig = field(default_factory=AtariDemoConfig)
    loss: AtariLossConfig = field(default_factory=AtariLossConfig)
    optim: AtariOptimConfig = field(default_factory=AtariOptimConfig)
    logger: AtariLoggerConfig = field(default_factory=AtariLoggerConfig)

    @property
    def frames_per_batch(self) -> int:
        """Agent steps per collected batch (each is 4 game frames)."""
        return self.env.num_envs * self.loss.n_steps

    def validate(self) -> AtariConfig:
        """Raises ``ValueError`` naming the bad setting and what is allowed (one line), before
        anything is built: every setting's type and range, then the combinations."""
        if self.variant not in ATARI_VARIANTS:
            raise ValueError(f"unknown Atari variant {self.variant!r}; choose one of {ATARI_VARIANTS}")
        check_types(self, recurse=False)
        if self.compile not in AtariEncoder.COMPILE_MODES:
            raise ValueError(f"compile={self.compile!r}: choose one of {AtariEncoder.COMPILE_MODES}")
        if self.idm_encoder not in IDM_ENCODERS:
            raise ValueError(
                f"idm_encoder={self.idm_encoder!r}: choose one of {IDM_ENCODERS} "
                "(shared: the paper's one CNN; own: the inverse model's own CNN)"
            )
        if self.init not in INITS:
            raise ValueError(f"init={self.init!r}: choose one of {INITS}")
        self.env.validate()
        self.collector.validate()
        self.validate_run()  # the settings every family shares: sizes, seed, frames, demo, loss, optim, logger, ppo
        if self.loss.explore_envs:
            raise ValueError(
                "loss.explore_envs (explorer env slots) is built for the gymnasium family; Atari's "
                "collector does not take it yet"
            )
        if self.rl != "a2c":
            raise ValueError(
                f"rl={self.rl!r}: Atari runs the paper's A2C only for now (rl=ppo is built for the gymnasium family)"
            )
        if self.loss.idm_forward_coeff > 0:
            raise ValueError(
                "loss.idm_forward_coeff > 0 (the forward head P_f over next states) needs discrete "
                "states; Atari frames have none"
            )
        if get_variant(self.variant).bc is not None and not self.demo.path:
            raise ValueError(
                f"variant {self.variant!r} needs expert demos: record them with recipes/atari_demos.py "
                "and pass demo.path=<folder>"
            )
        if self.collector.backend in WORKER_KINDS and self.env.num_envs % self.collector.workers:
            raise ValueError(f"collector.workers={self.collector.workers} must divide env.num_envs={self.env.num_envs}")
        if self.env.num_envs % self.collector.env_groups:
            raise ValueError(
                f"collector.env_groups={self.collector.env_groups} must divide env.num_envs={self.env.num_envs}"
            )
        resolve_device(self.device)
        if self.total_frames < 4 * self.frames_per_batch:
            raise ValueError(
                f"total_frames={self.total_frames} (game frames) is less than one batch "
                f"(env.num_envs * loss.n_steps = {self.frames_per_batch} agent steps = "
                f"{4 * self.frames_per_batch} frames)"
            )
        return self


def atari_config(d: dict[str, Any]) -> AtariConfig:
    """An :class:`AtariConfig` from nested dicts (e.g. Hydra's)."""
    return dataclass_from_dict(AtariConfig, d)


def _make_env(cfg: AtariConfig, num_envs: int | None = None, seed: int | None = None) -> TransformedEnv:
    env = AtariEnv(
        cfg.env.game,
        num_envs or cfg.env.num_envs,
        seed=cfg.seed if seed is None else seed,
        num_threads=cfg.env.num_threads,
        noop_max=cfg.env.noop_max,
        max_episode_frames=cfg.env.max_episode_frames,
    )
    # episode score (raw, unclipped game reward) for the learning curve
    return TransformedEnv(env, RewardSum(in_keys=["score"], out_keys=["episode_score"]))


def _worker_env(cfg: AtariConfig, i: int) -> TransformedEnv:
    """The games of collector worker ``i``: its share of ``env.num_envs``, its own seed and
    its share of the ALE threads."""
    workers = cfg.collector.workers
    env = AtariEnv(
        cfg.env.game,
        cfg.env.num_envs // workers,
        seed=cfg.seed + 1000 * i,
        num_threads=max(1, cfg.env.num_threads // workers),
        noop_max=cfg.env.noop_max,
        max_episode_frames=cfg.env.max_episode_frames,
    )
    return TransformedEnv(env, RewardSum(in_keys=["score"], out_keys=["episode_score"]))


#: how to record Atari demos (the end of the messages that refuse a demo folder)
DEMO_RECIPE = "record them with python recipes/atari_demos.py expert=<model.pt> out=<folder> (then demo.path=<folder>)"


def _check_demo_metadata(meta: dict, cfg: AtariConfig, env: AtariEnv, path: str) -> None:
    if meta.get("game") != cfg.env.game:
        raise ValueError(f"{path}: demos are for {meta.get('game')!r}, this run plays {cfg.env.game!r}")
    if meta.get("preprocessing") != env.preprocessing:
        raise ValueError(
            f"{path}: demos were recorded with preprocessing {meta.get('preprocessing')}, this run uses "
            f"{env.preprocessing}; record them again with the same settings"
        )


def _check_frame_stacks(demos, path: str, sample: int = 256) -> None:
    # a pair (s, s') of a real trajectory shares 3 of its 4 stacked frames: s'[:-1] == s[1:]
    n = demos.batch_size.numel()
    idx = torch.randperm(n, generator=torch.Generator().manual_seed(0))[:sample]
    s, s2 = (
        demos["observation"].reshape(n, *demos["observation"].shape[-3:])[idx],
        demos["next", "observation"].reshape(n, *demos["observation"].shape[-3:])[idx],
    )
    ok = (s2[:, :-1] == s[:, 1:]).flatten(1).all(-1)
    if not bool(ok.all()):
        raise ValueError(
            f"{path}: {int((~ok).sum())} of {len(idx)} sampled pairs (s, s') do not share their stacked "
            "frames (s' should drop the oldest frame of s and add one); these are not recorded "
            "trajectories (random or damaged frames?)"
        )


#: where the inverse model's CNN comes from (AtariConfig.idm_encoder)
IDM_ENCODERS = ("shared", "own")


def make_inverse_encoder(cfg: AtariConfig) -> AtariEncoder:
    """The inverse model's own CNN (``idm_encoder=own``): the actor's architecture, init and
    compile mode, separate weights."""
    encoder = AtariEncoder(channels_last=cfg.collector.backend != "ray")
    if cfg.init == "orthogonal":
        orthogonal_init_(encoder, math.sqrt(2))
    if cfg.compile != "off":
        encoder.compile_cnn(cfg.compile)
    return encoder


# a checkpoint is resumed only by a run that agrees on these (total_frames may grow; threads and device may change)
_RESUME_KEYS = (
    "variant",
    "seed",
    "rank",
    "d_state",
    "d",
    "mlp_layers",
    "init",
    "idm_encoder",
    "env",
    "demo",
    "loss",
    "optim",
)
_RESUME_IGNORE = ("env.num_threads",)


@dataclass
class AtariSetup(Setup):
    """Atari's :class:`Setup`: the game batch its preprocessing and actions are read from, and
    the AtariCollector's env batches (None with the other collector backends)."""

    base: Any = None
    envs: list | None = None


class AtariFamily(EnvFamily):
    """Atari in the one run assembly (:func:`~torchrl_hybrid.trainers.run.build_run`): the
    paper's CNN shared by actor, critic and inverse model (``idm_encoder=own``: the inverse
    model's own), the games on the CPU, demos
    recorded by :func:`~torchrl_hybrid.experts.record_demos`."""

    name = "atari"
    resume_keys = _RESUME_KEYS
    resume_ignore = _RESUME_IGNORE
    init_keys = ("env.game",)  # the CNN is the same for every game; the action count and meaning are not
    checkpoints_per_run = 10
    return_key = ("next", "episode_score")
    loss_extra = MappingProxyType(
        {"value_estimator_kwargs": {"skip_existing": True}}
    )  # values come from NextStateValueHook

    def setup(self, cfg: AtariConfig, variant, device, generator) -> AtariSetup:
        # the games run on the CPU; networks, learner and demos live on `device`
        envs = None
        if cfg.collector.backend == "atari":
            envs = AtariCollector.make_envs(
                cfg.env.game,
                cfg.env.num_envs,
                groups=cfg.collector.env_groups,
                seed=cfg.seed,
                num_threads=cfg.env.num_threads,
                noop_max=cfg.env.noop_max,
                max_episode_frames=cfg.env.max_episode_frames,
            )
            env = base = envs[0]
        elif cfg.collector.backend in WORKER_KINDS:
            env = _make_env(cfg, num_envs=1)  # specs only: the workers step the games
            base = env.base_env
        else:
            env = _make_env(cfg)
            base = env.base_env
        setup = AtariSetup(env, base.n_actions, base=base, envs=envs)
        if variant.bc is not None:
            try:
                setup.demos, meta = load_demos(
                    cfg.demo.path,
                    obs_shape=tuple(base.observation_spec["observation"].shape[1:]),
                    obs_dtype=torch.uint8,
                    require_metadata=DEMO_RECIPE,
                )
                _check_demo_metadata(meta, cfg, base, cfg.demo.path)
                _check_frame_stacks(setup.demos, cfg.demo.path)
                # pairs chain within a trajectory (s'_t == s_{t+1}); sampled, as the frame stacks
                check_trajectories(setup.demos, cfg.demo.path, DEMO_RECIPE, sample=256)
            except BaseException:
                self.close_envs(setup)
                raise
        return setup

    def close_envs(self, setup: AtariSetup) -> None:
        for env in setup.envs or [setup.env]:
            env.close()

    def frame_skip(self, setup: AtariSetup) -> int:
        return setup.base.preprocessing["frameskip"]

    def networks(self, cfg: AtariConfig, variant, setup: AtariSetup) -> Networks:
        # RayCollector sends the weights through torch.distributed, which takes contiguous tensors
        # only: no channels-last convolution weights there (same numbers, another memory layout)
        encoder = AtariEncoder(channels_last=False) if cfg.collector.backend == "ray" else None
        actor, critic, encoder, policy = make_atari_actor_critic(setup.n_actions, encoder=encoder, init=cfg.init)
        if cfg.compile != "off":
            encoder.compile_cnn(cfg.compile)
        if cfg.idm_encoder == "own":  # the inverse model's own CNN, built only for variants that have one
            return Networks(actor, critic, lambda: make_inverse_encoder(cfg), policy, encoder)
        return Networks(actor, critic, lambda: encoder, policy, encoder)  # one CNN for all

    def collector(self, cfg: AtariConfig, setup: AtariSetup, policy, device, total_steps: int):
        if cfg.collector.backend == "atari":
            return AtariCollector(
                setup.envs,
                policy,
                frames_per_batch=cfg.frames_per_batch,
                total_frames=total_steps,
                device=device,
                keep_features=cfg.collector.keep_features,
            )
        if cfg.collector.backend in WORKER_KINDS:
            fns = [functools.partial(_worker_env, cfg, i) for i in range(cfg.collector.workers)]
            return make_worker_collector(
                cfg.collector.backend,
                fns,
                policy,
                frames_per_batch=cfg.frames_per_batch,
                total_frames=total_steps,
                address=cfg.collector.address,
                worker_gpus=cfg.collector.worker_gpus,
            )
        return Collector(
            setup.env,
            policy,
            frames_per_batch=cfg.frames_per_batch,
            total_frames=total_steps,
            env_device="cpu",
            policy_device=device,
            storing_device=device,
            auto_register_policy_transforms=False,
        )

    def uses_workers(self, cfg: AtariConfig) -> bool:
        return cfg.collector.backend in WORKER_KINDS

    def sampler(self, cfg: AtariConfig, setup: AtariSetup):
        return (
            CurriculumSampler(cfg.demo.curriculum_k0, cfg.demo.curriculum_frames_per_step)
            if cfg.demo.curriculum
            else None
        )

    def register_hooks(self, run: Run) -> None:
        if run.variant.rl:
            NextStateValueHook(run.critic).register(run.trainer)

    def register_late_hooks(self, run: Run) -> None:
        # the games' emulator state is not saved, so a resumed run is not bit-exact; its random
        # state (CPU and CUDA generators) is
        RandomStateHook().register(run.trainer)

    def evaluator(self, run: Run):
        inverse_model, demos = run.inverse_model, run.demos
        if inverse_model is None or demos is None:
            return dict
        acc_pairs = None
        n = min(run.cfg.logger.accuracy_pairs, demos.batch_size.numel())
        if EXPERT_ACTION_KEY in demos.keys() and n > 0:  # accuracy_pairs=0: the column off (NaN)
            acc_pairs = demos[torch.randperm(demos.batch_size.numel(), generator=torch.Generator().manual_seed(0))[:n]]
            acc_pairs = acc_pairs.to(run.device)
        # NaN where the demos carry no true actions (the column is always there)
        return lambda: {
            IDM_ACCURACY_EXPERT: math.nan if acc_pairs is None else inverse_model_accuracy(inverse_model, acc_pairs)
        }

    def finish(self, run: Run) -> tuple[dict, dict]:
        cfg, base, rows = run.cfg, run.setup.base, run.metrics.rows
        evaluation = None
        if cfg.logger.eval_episodes > 0:
            evaluation = evaluate_atari(
                run.actor,
                cfg.env.game,
                base.preprocessing,
                episodes=cfg.logger.eval_episodes,
                num_envs=min(cfg.env.num_envs, cfg.logger.eval_episodes),
                seed=cfg.seed + 10_000,
                num_threads=cfg.env.num_threads,
                progress=cfg.logger.progress_bar,
                device=run.device,
            )
        finished = [r["return_mean"] for r in rows if r["episodes"]]
        results = {
            "head": {"game": cfg.env.game},
            "final_return": finished[-1] if finished else None,
            IDM_ACCURACY_EXPERT: finite(rows[-1].get(IDM_ACCURACY_EXPERT)) if rows else None,
            IDM_ACCURACY_AGENT: finite(rows[-1].get(IDM_ACCURACY_AGENT)) if rows else None,
            "eval_return": None if evaluation is None else evaluation["mean"],
            "evaluation": evaluation,
        }
        return results, {"n_actions": base.n_actions, "preprocessing": base.preprocessing, "evaluation": evaluation}

    def experiment_name(self, cfg: AtariConfig) -> str:
        return f"{cfg.env.game}_{cfg.variant}_s{cfg.seed}"

    def title(self, cfg: AtariConfig) -> str:
        return f"{cfg.env.game}, {cfg.variant}, seed {cfg.seed}"


AtariRun = Run  # the name earlier versions exported


def build_atari(cfg: AtariConfig) -> Run:
    """Builds the env, networks, losses, collector and TorchRL trainer of one run
    (hooks registered), without training: ``build_atari(cfg).trainer.train()``."""
    return build_run(cfg, AtariFamily())


def train_atari(cfg: AtariConfig) -> dict[str, Any]:
    """Trains one agent (``hybrid_dual``, ``hybrid_mlp``, ``bc_dual`` or ``a2c``) and
    writes ``metrics.csv``, ``summary.json``, ``learning_curve.png``, ``model.pt``."""
    return train_run(cfg, AtariFamily())
