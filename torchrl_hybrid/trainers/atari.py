"""The Atari pipeline: expert training, demonstration recording, hybrid training.

The recipes ``recipes/atari_expert.py``, ``recipes/atari_demos.py`` and
``recipes/atari.py`` are Hydra front-ends over :func:`train_atari`,
:func:`record_demos`; tests call these directly. Same losses, hooks and trainer
as Taxi; only the networks (a shared CNN), the env and the demo source differ.
"""
from __future__ import annotations

import dataclasses
import functools
import json
import logging
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from tqdm import tqdm
from torchrl.collectors import Collector
from torchrl.envs import RewardSum, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.record.loggers import get_logger
from torchrl.trainers import UpdateWeights

from torchrl_hybrid.collectors import WORKER_KINDS, AtariCollector, make_worker_collector
from torchrl_hybrid.data import (
    EXPERT_ACTION_KEY,
    CurriculumSampler,
    load_demos,
    pairs_from_trajectories,
    save_demos,
)
from torchrl_hybrid.envs.atari import AtariEnv
from torchrl_hybrid.modules import AtariEncoder, DualInverseDynamics, MLPInverseDynamics, make_atari_actor_critic
from torchrl_hybrid.trainers.evaluation import inverse_model_accuracy
from torchrl_hybrid.trainers.hooks import MetricsHook, NextStateValueHook
from torchrl_hybrid.trainers.hybrid import (
    attach_demonstrations,
    get_variant,
    make_hybrid_loss,
    make_trainer,
    param_groups,
    resume_trainer,
)
from torchrl_hybrid.utils.config import dataclass_from_dict
from torchrl_hybrid.utils.device import resolve_device
from torchrl_hybrid.utils.files import prepare_out_dir
from torchrl_hybrid.utils.metrics import IDM_ACCURACY_AGENT, IDM_ACCURACY_EXPERT
from torchrl_hybrid.utils.plotting import plot_learning_curve

__all__ = ["AtariConfig", "AtariRun", "atari_config", "build_atari", "train_atari", "evaluate_atari", "record_demos",
           "load_expert"]

ATARI_VARIANTS = ("hybrid_dual", "hybrid_mlp", "bc_dual", "a2c")


@dataclass
class AtariEnvConfig:
    game: str = "Pong"
    num_envs: int = 16
    num_threads: int = 2
    noop_max: int = 30
    max_episode_frames: int = 108_000


@dataclass
class AtariCollectorConfig:
    backend: str = "atari"  # atari (AtariCollector) | torchrl (TorchRL's generic Collector, the reference path)
    # | multi_sync (TorchRL's MultiSyncCollector, `workers` processes) | ray (RayCollector, `workers` Ray actors)
    workers: int = 2        # multi_sync / ray: env.num_envs is split evenly between them
    address: str | None = None  # ray: the cluster to join; None starts a local one
    env_groups: int = 1     # atari backend: groups of games stepped as a pipeline (1 = one vector env)
    keep_features: bool = True  # atari backend: the learner reuses the encoder pass made during collection


@dataclass
class AtariDemoConfig:
    path: str | None = None
    batch_size: int = 32
    curriculum: bool = True
    curriculum_k0: int = 10
    curriculum_frames_per_step: int = 8000


@dataclass
class AtariLossConfig:
    n_steps: int = 5
    gamma: float = 0.99
    critic_coeff: float = 0.5
    entropy_coeff: float = 0.01
    idm_action_coeff: float = 1.0
    idm_embedding_coeff: float = 0.0  # see recipes/config/atari.yaml
    bc_coeff: float = 1.0
    bc_start_frames: int = 100_000
    bc_labels: str = "argmax"         # argmax (the paper) | soft (cross-entropy to P_i)
    bc_confidence: float = 0.0         # clone only pairs with max P_i >= this (0: all)
    bc_entropy_floor: float = 0.0      # penalise policy entropy below this on expert states (0: off)
    bc_ready_accuracy: float = 0.0     # >0: BC starts once the inverse model's held-out accuracy reaches this


@dataclass
class AtariOptimConfig:
    lr: float = 7e-4
    eps: float = 1e-5
    alpha: float = 0.99
    max_grad_norm: float = 0.5


@dataclass
class AtariLoggerConfig:
    backend: str = "csv"
    log_every_frames: int = 40_000
    accuracy_pairs: int = 512
    eval_episodes: int = 0  # episodes played by the final policy (sampling); stored in summary.json and model.pt
    progress_bar: bool = True
    checkpoint: bool = True


@dataclass
class AtariConfig:
    variant: str = "hybrid_dual"
    seed: int = 0
    total_frames: int = 2_000_000
    rank: int = 8
    d_state: int = 128
    d: int = 128
    out_dir: str = "outputs/atari"
    threads: int = 2
    init: str = "orthogonal"
    resume: bool = False
    overwrite: bool = False
    device: str = "auto"
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

    def validate(self) -> "AtariConfig":
        if self.variant not in ATARI_VARIANTS:
            raise ValueError(f"unknown Atari variant {self.variant!r}; choose one of {ATARI_VARIANTS}")
        if self.rank < 1:
            raise ValueError(f"rank must be >= 1, got {self.rank}")
        if get_variant(self.variant).bc is not None and not self.demo.path:
            raise ValueError(
                f"variant {self.variant!r} needs expert demos: record them with recipes/atari_demos.py "
                "and pass demo.path=<folder>"
            )
        if self.collector.backend not in ("atari", "torchrl", *WORKER_KINDS):
            raise ValueError(f"collector.backend={self.collector.backend!r}: choose atari, torchrl, "
                             + " or ".join(WORKER_KINDS))
        if self.collector.backend in WORKER_KINDS and (self.collector.workers < 1
                                                        or self.env.num_envs % self.collector.workers):
            raise ValueError(f"collector.workers={self.collector.workers} must divide env.num_envs={self.env.num_envs}")
        if self.collector.env_groups < 1 or self.env.num_envs % self.collector.env_groups:
            raise ValueError(f"collector.env_groups={self.collector.env_groups} must divide "
                             f"env.num_envs={self.env.num_envs}")
        if self.collector.env_groups > 1 and self.collector.backend != "atari":
            raise ValueError("collector.env_groups > 1 needs collector.backend=atari")
        resolve_device(self.device)
        if self.total_frames < 4 * self.frames_per_batch:
            raise ValueError(f"total_frames={self.total_frames} (game frames) is less than one batch "
                             f"({self.frames_per_batch} agent steps = {4 * self.frames_per_batch} frames)")
        return self


def atari_config(d: dict[str, Any]) -> AtariConfig:
    """An :class:`AtariConfig` from nested dicts (e.g. Hydra's)."""
    return dataclass_from_dict(AtariConfig, d)


def _make_env(cfg: AtariConfig, num_envs: int | None = None, seed: int | None = None) -> TransformedEnv:
    env = AtariEnv(cfg.env.game, num_envs or cfg.env.num_envs, seed=cfg.seed if seed is None else seed,
                   num_threads=cfg.env.num_threads, noop_max=cfg.env.noop_max,
                   max_episode_frames=cfg.env.max_episode_frames)
    # episode score (raw, unclipped game reward) for the learning curve
    return TransformedEnv(env, RewardSum(in_keys=["score"], out_keys=["episode_score"]))


def _worker_env(cfg: AtariConfig, i: int) -> TransformedEnv:
    """The games of collector worker ``i``: its share of ``env.num_envs``, its own seed and
    its share of the ALE threads."""
    workers = cfg.collector.workers
    env = AtariEnv(cfg.env.game, cfg.env.num_envs // workers, seed=cfg.seed + 1000 * i,
                   num_threads=max(1, cfg.env.num_threads // workers), noop_max=cfg.env.noop_max,
                   max_episode_frames=cfg.env.max_episode_frames)
    return TransformedEnv(env, RewardSum(in_keys=["score"], out_keys=["episode_score"]))


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
    s, s2 = demos["observation"].reshape(n, *demos["observation"].shape[-3:])[idx], \
        demos["next", "observation"].reshape(n, *demos["observation"].shape[-3:])[idx]
    ok = (s2[:, :-1] == s[:, 1:]).flatten(1).all(-1)
    if not bool(ok.all()):
        raise ValueError(f"{path}: {int((~ok).sum())} of {len(idx)} sampled pairs (s, s') do not share their stacked "
                         "frames (s' should drop the oldest frame of s and add one); these are not recorded "
                         "trajectories (random or damaged frames?)")


@dataclass
class AtariRun:
    """Everything :func:`build_atari` wires together (see :func:`train_atari`)."""

    cfg: AtariConfig
    trainer: Any
    env: TransformedEnv
    actor: Any
    critic: Any
    encoder: Any
    inverse_model: Any
    collection_policy: Any
    loss: Any
    metrics: MetricsHook
    out: Path
    device: torch.device
    resumed_from: int = 0
    lock: Any = None  # the out_dir lock (released when the run is closed or the process ends)


def build_atari(cfg: AtariConfig) -> AtariRun:
    """Builds the env, networks, losses, collector and TorchRL trainer of one run
    (hooks registered), without training: ``build_atari(cfg).trainer.train()``."""
    cfg.validate()
    logging.getLogger("torchrl").setLevel(logging.WARNING)
    os.environ.setdefault("TQDM_MININTERVAL", "1" if sys.stderr.isatty() else "30")
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    device = resolve_device(cfg.device)
    variant = get_variant(cfg.variant)
    out = Path(cfg.out_dir)
    lock = prepare_out_dir(out, resume=cfg.resume, overwrite=cfg.overwrite)  # held while `run` lives

    # the games run on the CPU; networks, learner and demos live on `device`
    if cfg.collector.backend == "atari":
        envs = AtariCollector.make_envs(cfg.env.game, cfg.env.num_envs, groups=cfg.collector.env_groups,
                                        seed=cfg.seed, num_threads=cfg.env.num_threads, noop_max=cfg.env.noop_max,
                                        max_episode_frames=cfg.env.max_episode_frames)
        env = base = envs[0]
    elif cfg.collector.backend in WORKER_KINDS:
        env = _make_env(cfg, num_envs=1)  # specs only: the workers step the games
        base = env.base_env
    else:
        env = _make_env(cfg)
        base = env.base_env
    demos = None
    if variant.bc is not None:
        demos, meta = load_demos(cfg.demo.path, obs_shape=tuple(base.observation_spec["observation"].shape[1:]),
                                 obs_dtype=torch.uint8)
        _check_demo_metadata(meta, cfg, base, cfg.demo.path)
        _check_frame_stacks(demos, cfg.demo.path)

    # RayCollector sends the weights through torch.distributed, which takes contiguous tensors
    # only: no channels-last convolution weights there (same numbers, another memory layout)
    encoder = AtariEncoder(channels_last=False) if cfg.collector.backend == "ray" else None
    actor, critic, encoder, collection_policy = make_atari_actor_critic(base.n_actions, encoder=encoder, init=cfg.init)
    inverse_model = None
    if variant.inverse_model == "dual":
        inverse_model = DualInverseDynamics(encoder, base.n_actions, d_state=cfg.d_state, d=cfg.d, rank=cfg.rank)
    elif variant.inverse_model == "mlp":
        inverse_model = MLPInverseDynamics(encoder, base.n_actions, d_state=cfg.d_state, hidden=cfg.d)
    lc = cfg.loss
    loss = make_hybrid_loss(
        variant, actor, critic, inverse_model, gamma=lc.gamma, critic_coeff=lc.critic_coeff,
        entropy_coeff=lc.entropy_coeff, idm_action_coeff=lc.idm_action_coeff,
        idm_embedding_coeff=lc.idm_embedding_coeff, bc_coeff=lc.bc_coeff, bc_labels=lc.bc_labels,
        bc_confidence=lc.bc_confidence, bc_entropy_floor=lc.bc_entropy_floor,
        value_estimator_kwargs={"skip_existing": True},  # values come from NextStateValueHook
    ).to(device)  # moves the shared encoder, heads and inverse model with it
    optimizer = torch.optim.RMSprop(param_groups(loss), lr=cfg.optim.lr, eps=cfg.optim.eps, alpha=cfg.optim.alpha)
    # total_frames, bc_start_frames and the curriculum count game frames, as the paper
    # does (4 per agent step); the collector counts agent steps
    skip = base.preprocessing["frameskip"]
    agent_steps = -(-cfg.total_frames // skip)
    if cfg.collector.backend == "atari":
        collector = AtariCollector(envs, collection_policy, frames_per_batch=cfg.frames_per_batch,
                                   total_frames=agent_steps, device=device,
                                   keep_features=cfg.collector.keep_features)
    elif cfg.collector.backend in WORKER_KINDS:
        fns = [functools.partial(_worker_env, cfg, i) for i in range(cfg.collector.workers)]
        collector = make_worker_collector(cfg.collector.backend, fns, collection_policy,
                                          frames_per_batch=cfg.frames_per_batch, total_frames=agent_steps,
                                          device=device, address=cfg.collector.address)
    else:
        collector = Collector(env, collection_policy, frames_per_batch=cfg.frames_per_batch, total_frames=agent_steps,
                              env_device="cpu", policy_device=device, storing_device=device,
                              auto_register_policy_transforms=False)
    logger = None
    if cfg.logger.backend != "none":
        logger = get_logger(cfg.logger.backend, logger_name=str(out / "logs"),
                            experiment_name=f"{cfg.env.game}_{cfg.variant}_s{cfg.seed}")
    trainer = make_trainer(
        collector=collector, loss=loss, optimizer=optimizer, total_frames=cfg.total_frames,
        clip_norm=cfg.optim.max_grad_norm, logger=logger, progress_bar=cfg.logger.progress_bar,
        save_trainer_file=out / "checkpoint" if cfg.logger.checkpoint else None,
        save_trainer_interval=max(cfg.total_frames // 10, cfg.frames_per_batch),
        frame_skip=skip,
    )
    if variant.rl:
        NextStateValueHook(critic).register(trainer)
    if cfg.collector.backend in WORKER_KINDS:  # the workers' policy copies get the learner's weights every batch
        UpdateWeights(collector, update_weights_interval=1).register(trainer)
    if demos is not None:
        sampler = (CurriculumSampler(cfg.demo.curriculum_k0, cfg.demo.curriculum_frames_per_step)
                   if cfg.demo.curriculum else None)
        attach_demonstrations(trainer, loss, demos, sampler=sampler, batch_size=cfg.demo.batch_size,
                              bc_coeff=lc.bc_coeff, bc_start_frames=lc.bc_start_frames,
                              bc_ready_accuracy=lc.bc_ready_accuracy, device=device)

    acc_pairs = None
    if inverse_model is not None and demos is not None and EXPERT_ACTION_KEY in demos.keys():
        n = min(cfg.logger.accuracy_pairs, demos.batch_size.numel())
        acc_pairs = demos[torch.randperm(demos.batch_size.numel(), generator=torch.Generator().manual_seed(0))[:n]]
        acc_pairs = acc_pairs.to(device)

    def evaluator():
        if inverse_model is None or demos is None:
            return {}
        # NaN where the demos carry no true actions (the column is always there)
        return {IDM_ACCURACY_EXPERT: math.nan if acc_pairs is None else inverse_model_accuracy(inverse_model, acc_pairs)}

    metrics = MetricsHook(out / "metrics.csv", cfg.logger.log_every_frames, evaluator,
                          pbar_keys=("return_mean",), return_key=("next", "episode_score"))
    metrics.register(trainer)
    resumed = resume_trainer(trainer, out, dataclasses.asdict(cfg), _RESUME_KEYS, _RESUME_IGNORE) if cfg.resume else 0
    (out / "config.json").write_text(json.dumps(dataclasses.asdict(cfg), indent=2))
    return AtariRun(cfg, trainer, env, actor, critic, encoder, inverse_model, collection_policy, loss, metrics, out,
                    device, resumed, lock)


# a checkpoint is resumed only by a run that agrees on these (total_frames may grow; threads and device may change)
_RESUME_KEYS = ("variant", "seed", "rank", "d_state", "d", "init", "env", "demo", "loss", "optim")
_RESUME_IGNORE = ("env.num_threads",)


def _finite(x) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def train_atari(cfg: AtariConfig) -> dict[str, Any]:
    """Trains one agent (``hybrid_dual``, ``hybrid_mlp``, ``bc_dual`` or ``a2c``) and
    writes ``metrics.csv``, ``summary.json``, ``learning_curve.png``, ``model.pt``."""
    run = build_atari(cfg)
    trainer, metrics, out, env = run.trainer, run.metrics, run.out, run.env
    base = env.base_env if isinstance(env, TransformedEnv) else env
    actor, critic, inverse_model = run.actor, run.critic, run.inverse_model
    t0 = time.perf_counter()
    trainer.train()
    train_time = time.perf_counter() - t0
    evaluation = None
    if cfg.logger.eval_episodes > 0:
        evaluation = evaluate_atari(actor, cfg.env.game, base.preprocessing, episodes=cfg.logger.eval_episodes,
                                    num_envs=min(cfg.env.num_envs, cfg.logger.eval_episodes), seed=cfg.seed + 10_000,
                                    num_threads=cfg.env.num_threads, progress=cfg.logger.progress_bar,
                                    device=run.device)
    finished = [r["return_mean"] for r in metrics.rows if r["episodes"]]
    summary = {
        "game": cfg.env.game, "variant": cfg.variant, "seed": cfg.seed, "frames": int(trainer.collected_frames),
        "final_return": finished[-1] if finished else None,
        IDM_ACCURACY_EXPERT: _finite(metrics.rows[-1].get(IDM_ACCURACY_EXPERT)) if metrics.rows else None,
        IDM_ACCURACY_AGENT: _finite(metrics.rows[-1].get(IDM_ACCURACY_AGENT)) if metrics.rows else None,
        "eval_return": None if evaluation is None else evaluation["mean"],
        "evaluation": evaluation,
        "resumed_from_frames": run.resumed_from,
        "train_time_s": round(train_time, 2),  # this piece only, when resumed
        "frames_per_s": round((trainer.collected_frames - run.resumed_from) / train_time, 1),
        "config": dataclasses.asdict(cfg),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    torch.save({"actor": actor.state_dict(), "critic": critic.state_dict(),
                "inverse_model": None if inverse_model is None else inverse_model.state_dict(),
                "n_actions": base.n_actions, "preprocessing": base.preprocessing,
                "config": dataclasses.asdict(cfg), "evaluation": evaluation}, out / "model.pt")
    plot_learning_curve(metrics.rows, out / "learning_curve.png", title=f"{cfg.env.game}, {cfg.variant}, seed {cfg.seed}")
    trainer.collector.shutdown()
    run.lock.close()
    return summary


@torch.no_grad()
def evaluate_atari(
    actor, game: str, preprocessing: dict, *, episodes: int = 16, num_envs: int = 16, seed: int = 0,
    deterministic: bool = False, num_threads: int = 2, max_steps: int | None = None, progress: bool = False,
    device: str | torch.device | None = None,
) -> dict[str, Any]:
    """Plays ``episodes`` whole episodes (all lives) with ``actor`` and returns the
    raw game scores: ``{"mean", "std", "scores", "episodes", "deterministic"}``.
    ``max_steps`` (agent steps per env) stops early; unfinished episodes are not counted.
    The actor runs on ``device`` (default: where its parameters are), the games on the CPU."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    device = _module_device(actor) if device is None else resolve_device(device)
    torch.manual_seed(seed)
    env = AtariEnv(game, num_envs, seed=seed, num_threads=num_threads, noop_max=preprocessing["noop_max"],
                   max_episode_frames=preprocessing["max_episode_frames"])
    env.check_policy(actor)
    td = env.reset()
    running = torch.zeros(num_envs)
    scores: list[float] = []
    etype = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    bar = tqdm(total=episodes, desc=f"{game} evaluation", disable=not progress)
    steps = 0
    while len(scores) < episodes and (max_steps is None or steps < max_steps):
        with set_exploration_type(etype):
            td = actor(td.to(device)).to("cpu")
        td, root = env.step_and_maybe_reset(td)
        running += td["next", "score"].reshape(num_envs)
        for i in torch.nonzero(td["next", "done"].reshape(num_envs)).flatten().tolist():
            if len(scores) < episodes:
                scores.append(float(running[i]))
                bar.update(1)
            running[i] = 0.0
        td, steps = root, steps + 1
    bar.close()
    env.close()
    t = torch.tensor(scores)
    return {"mean": float(t.mean()) if scores else None, "std": float(t.std()) if len(scores) > 1 else None,
            "scores": scores, "episodes": len(scores), "deterministic": deterministic}


def _module_device(module) -> torch.device:
    p = next(iter(module.parameters()), None)
    return p.device if p is not None else torch.device("cpu")


def load_expert(path: str | Path, device: str | torch.device = "cpu"):
    """The actor of a checkpoint written by :func:`train_atari` (``model.pt``), on
    ``device`` whatever device it was saved from, and the checkpoint's metadata."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"expert checkpoint {str(path)!r} does not exist; train one with recipes/atari_expert.py")
    device = resolve_device(device)
    if path.is_dir() or path.stat().st_size == 0:
        raise ValueError(f"{path} is {'a folder' if path.is_dir() else 'empty'}, not a model.pt written by train_atari")
    try:
        ckpt = torch.load(path, weights_only=False, map_location="cpu")
    except Exception as err:  # truncated, random bytes, another format
        raise ValueError(f"{path} is not a model.pt written by train_atari ({type(err).__name__}: {err})") from None
    need = ("n_actions", "actor", "preprocessing", "config")
    if not isinstance(ckpt, dict) or any(k not in ckpt for k in need):
        keys = sorted(ckpt) if isinstance(ckpt, dict) else type(ckpt).__name__
        raise ValueError(f"{path} is not an Atari checkpoint: it lacks {[k for k in need if k not in ckpt] if isinstance(ckpt, dict) else need} "
                         f"(it has {keys}; a Taxi model.pt?)")
    actor = make_atari_actor_critic(ckpt["n_actions"])[0]
    try:
        actor.load_state_dict(ckpt["actor"])
    except RuntimeError as err:
        raise ValueError(f"{path}: its actor does not fit the paper's Atari network ({err})") from None
    return actor.to(device), ckpt


@torch.no_grad()
def record_demos(
    expert_path: str | Path,
    out_path: str | Path,
    *,
    num_trajectories: int = 100,
    num_envs: int = 16,
    seed: int = 0,
    deterministic: bool = False,
    max_steps: int = 27_000,
    cut: str = "auto",
    progress: bool = True,
    device: str | torch.device = "auto",
    overwrite: bool = False,
) -> dict[str, Any]:
    """Plays the expert and saves ``num_trajectories`` state-only trajectories as a
    memory-mapped dataset of expert pairs with metadata. True actions go only under
    ``EXPERT_ACTION_KEY``.

    ``cut`` says where a trajectory ends (always at the episode's end or after
    ``max_steps`` at the latest): ``"life"`` at the first life lost (the paper);
    ``"point"`` at the first negative reward (a point lost: the analogue of a life in
    games without lives such as Pong, whose whole episodes run to thousands of steps);
    ``"episode"`` never earlier; ``"auto"`` = ``"life"`` when the game has lives,
    else ``"point"``.
    """
    if cut not in ("auto", "life", "point", "episode"):
        raise ValueError(f"cut={cut!r}: choose one of 'auto', 'life', 'point', 'episode'")
    if num_trajectories < 1 or max_steps < 1:
        raise ValueError(f"num_trajectories and max_steps must be >= 1, got {num_trajectories}, {max_steps}")
    out = Path(out_path)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not overwrite:  # before minutes of play
        raise ValueError(f"{out} already exists and is not empty; pass overwrite=true to replace it "
                         "or choose another folder")
    actor, ckpt = load_expert(expert_path, device)
    device = _module_device(actor)
    torch.manual_seed(seed)  # the expert's sampled actions: the same seed records the same demos
    game = ckpt["config"]["env"]["game"]
    pre = ckpt["preprocessing"]
    env = AtariEnv(game, num_envs, seed=seed, num_threads=ckpt["config"]["env"]["num_threads"],
                   noop_max=pre["noop_max"], max_episode_frames=pre["max_episode_frames"])
    env.check_policy(actor)
    td = env.reset()
    # per env: the trajectory being recorded, or None while waiting for the episode to end
    states: list[list[torch.Tensor] | None] = [[td["observation"][i].clone()] for i in range(num_envs)]
    actions: list[list[int]] = [[] for _ in range(num_envs)]
    scores = [0.0] * num_envs
    lives0 = td["lives"].squeeze(-1).clone()
    if cut == "auto":
        cut = "life" if bool((lives0 > 0).all()) else "point"
    trajs, acts, returns, ends = [], [], [], []
    etype = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    bar = tqdm(total=num_trajectories, desc=f"{game} demos", disable=not progress)
    while len(trajs) < num_trajectories:
        with set_exploration_type(etype):
            td = actor(td.to(device)).to("cpu")
        td, root = env.step_and_maybe_reset(td)
        nxt = td["next"]
        done = nxt["done"].squeeze(-1)
        lives = nxt["lives"].squeeze(-1)
        for i in range(num_envs):
            if states[i] is not None:
                states[i].append(nxt["observation"][i].clone())
                actions[i].append(int(td["action"][i]))
                scores[i] += float(nxt["score"][i])
                end = ("life" if cut == "life" and bool(lives[i] < lives0[i])
                       else "point" if cut == "point" and float(nxt["score"][i]) < 0
                       else "episode" if bool(done[i])
                       else "max_steps" if len(actions[i]) >= max_steps else None)
                if end is not None and len(trajs) < num_trajectories:
                    ends.append(end)
                    trajs.append(torch.stack(states[i]))
                    acts.append(torch.tensor(actions[i]))
                    returns.append(scores[i])
                    bar.update(1)
                    states[i] = None
            if bool(done[i]):  # a new episode starts: record it from its first state
                states[i], actions[i], scores[i] = [root["observation"][i].clone()], [], 0.0
                lives0[i] = root["lives"][i, 0]
        td = root
    bar.close()
    env.close()
    demos = pairs_from_trajectories(trajs, acts)
    lengths = [len(a) for a in acts]
    meta = {
        "game": game, "preprocessing": pre, "expert_checkpoint": str(Path(expert_path).resolve()),
        "expert_frames": ckpt["config"]["total_frames"], "num_trajectories": len(trajs),
        "returns": returns, "lengths": lengths, "ends": ends, "deterministic": deterministic, "seed": seed,
        "cut": {"life": "first life lost", "point": "first point lost (negative reward)",
                "episode": "episode end"}[cut] + f", episode end or {max_steps} steps",
    }
    save_demos(demos, out_path, meta, overwrite=overwrite)
    return meta
