"""The Taxi experiment: configuration, assembly and one training run.

``recipes/taxi.py`` is a thin Hydra front-end over :func:`train_taxi`; tests and
notebooks call :func:`train_taxi` directly with a :class:`TaxiConfig`.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torchrl.collectors import Collector
from torchrl.record.loggers import get_logger

from torchrl_hybrid.data import (
    EXPERT_ACTION_KEY,
    CurriculumSampler,
    VisitedStateSampler,
    apply_demo_noise,
    load_demos,
    save_demos,
    tabular_state_pairs,
    tabular_trajectories,
)
from torchrl_hybrid.envs import BACKENDS, TabularEnv, TabularModel, make_toy_text_env
from torchrl_hybrid.experts import expected_return, optimal_policy
from torchrl_hybrid.modules import (
    DualInverseDynamics,
    MLPInverseDynamics,
    OneHotEncoder,
    make_tabular_actor_critic,
)
from torchrl_hybrid.trainers.evaluation import evaluate_policy, inverse_model_accuracy
from torchrl_hybrid.trainers.hooks import MetricsHook, RunStateHook
from torchrl_hybrid.trainers.hybrid import (
    attach_demonstrations,
    get_variant,
    make_hybrid_loss,
    make_trainer,
    param_groups,
    resume_trainer,
)

# a checkpoint is resumed only by a run that agrees on these (total_frames may grow)
_RESUME_KEYS = ("variant", "seed", "rank", "d_state", "d", "mlp_layers", "identity_embedding", "env", "demo", "loss",
                "optim")
from torchrl_hybrid.utils.config import dataclass_from_dict
from torchrl_hybrid.utils.device import resolve_device
from torchrl_hybrid.utils.files import prepare_out_dir
from torchrl_hybrid.utils.plotting import plot_learning_curve

__all__ = ["TaxiConfig", "config_from_dict", "make_taxi_demos", "train_taxi"]

RHOS = ("visited", "uniform", "curriculum")
DEMO_FORMS = ("per_state", "trajectories")
LOGGERS = ("csv", "tensorboard", "wandb", "none")
ENGINES = ("torchrl", "batched")


@dataclass
class EnvConfig:
    env_id: str = "Taxi-v4"
    num_envs: int = 16
    backend: str = "auto"
    max_episode_steps: int = 50


@dataclass
class DemoConfig:
    form: str = "per_state"
    num_trajectories: int = 100
    path: str | None = None
    save_path: str | None = None
    eta: float = 0.0
    epsilon: float = 0.0
    epsilon_mode: str = "non_optimal"
    rho: str = "visited"
    batch_size: int = 32
    curriculum_k0: int = 10
    curriculum_frames_per_step: int = 8000


@dataclass
class LossConfig:
    n_steps: int = 2
    gamma: float = 0.99
    critic_coeff: float = 0.2
    entropy_coeff: float = 0.5
    idm_action_coeff: float = 2.0
    idm_embedding_coeff: float = 0.1
    idm_forward_coeff: float = 0.0
    bc_coeff: float = 2.0
    bc_start_frames: int = 0
    bc_labels: str = "argmax"         # argmax (the paper) | soft (cross-entropy to P_i)
    bc_confidence: float = 0.0         # clone only pairs with max P_i >= this (0: all)
    bc_entropy_floor: float = 0.0      # penalise policy entropy below this on expert states (0: off)
    bc_ready_accuracy: float = 0.0     # >0: BC starts once the inverse model's held-out accuracy reaches this


@dataclass
class OptimConfig:
    lr: float = 1e-3
    eps: float = 1e-5
    alpha: float = 0.99
    max_grad_norm: float = 0.5
    clip: str = "global"


@dataclass
class LoggerConfig:
    backend: str = "csv"
    log_every_frames: int = 2000
    eval_episodes: int = 100
    final_eval_episodes: int = 300
    progress_bar: bool = True
    checkpoint: bool = True


@dataclass
class TaxiConfig:
    """Every knob of a Taxi run; ``recipes/config/taxi.yaml`` documents each one."""

    variant: str = "hybrid_dual"
    seed: int = 0
    total_frames: int = 80_000
    rank: int = 2
    d_state: int = 128
    d: int = 128
    mlp_layers: int = 2
    identity_embedding: bool = True
    out_dir: str = "outputs/taxi"
    threads: int = 1
    engine: str = "torchrl"
    device: str = "auto"
    resume: bool = False
    overwrite: bool = False
    env: EnvConfig = field(default_factory=EnvConfig)
    demo: DemoConfig = field(default_factory=DemoConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)

    def validate(self) -> "TaxiConfig":
        """Raises ``ValueError`` naming the bad setting and what is allowed."""
        get_variant(self.variant)
        if self.engine == "batched" and self.resume:
            raise ValueError("resume=true needs engine=torchrl (the batched engine writes no checkpoint)")
        if resolve_device(self.device).type != "cpu" and self.engine == "batched" and self.device != "auto":
            raise ValueError(f"engine=batched runs on the CPU only; use device=cpu (or device=auto), "
                             f"or engine=torchrl for device={self.device}")

        def need(ok: bool, msg: str):
            if not ok:
                raise ValueError(msg)

        need(self.engine in ENGINES, f"engine must be one of {ENGINES}, got {self.engine!r}")
        need(self.rank >= 1, f"rank must be an integer >= 1, got {self.rank}")
        need(self.mlp_layers >= 1, f"mlp_layers must be >= 1, got {self.mlp_layers}")
        for name in ("eta", "epsilon"):
            v = getattr(self.demo, name)
            need(0.0 <= v < 1.0, f"demo.{name} must be in [0, 1), got {v}")
        need(self.demo.rho in RHOS, f"demo.rho must be one of {RHOS}, got {self.demo.rho!r}")
        need(self.demo.form in DEMO_FORMS, f"demo.form must be one of {DEMO_FORMS}, got {self.demo.form!r}")
        need(self.env.backend in BACKENDS, f"env.backend must be one of {BACKENDS}, got {self.env.backend!r}")
        need(self.env.num_envs >= 1, f"env.num_envs must be >= 1, got {self.env.num_envs}")
        need(self.env.max_episode_steps >= 1, f"env.max_episode_steps must be >= 1, got {self.env.max_episode_steps}")
        need(self.loss.n_steps >= 1, f"loss.n_steps must be >= 1, got {self.loss.n_steps}")
        need(
            self.total_frames >= self.frames_per_batch,
            f"total_frames={self.total_frames} is less than one batch (env.num_envs * loss.n_steps = {self.frames_per_batch})",
        )
        need(self.logger.backend in LOGGERS, f"logger.backend must be one of {LOGGERS}, got {self.logger.backend!r}")
        need(self.logger.eval_episodes >= 1 and self.logger.final_eval_episodes >= 1, "eval episode counts must be >= 1")
        return self

    @property
    def frames_per_batch(self) -> int:
        return self.env.num_envs * self.loss.n_steps


def config_from_dict(d: dict[str, Any]) -> TaxiConfig:
    """Builds a :class:`TaxiConfig` from nested dicts (e.g. Hydra's), rejecting unknown keys."""
    return dataclass_from_dict(TaxiConfig, d)


def make_taxi_demos(cfg: TaxiConfig, model: TabularModel, generator: torch.Generator):
    """The demo pairs of a run: the optimal expert's (or a file's), then noise."""
    policy, optimal = optimal_policy(model)
    if cfg.demo.path:
        demos, _ = load_demos(cfg.demo.path, obs_shape=(), obs_dtype=torch.long)
        s = torch.cat([demos["observation"], demos["next", "observation"]])
        if s.min() < 0 or s.max() >= model.n_states:
            raise ValueError(f"{cfg.demo.path}: states outside [0, {model.n_states}); demos are for another env")
        # every pair must be a transition of the env under some action (the table says which)
        obs, nxt = demos["observation"].reshape(-1), demos["next", "observation"].reshape(-1)
        possible = ((model.next_state[obs] == nxt.view(-1, 1, 1)) & (model.prob[obs] > 0)).flatten(1).any(-1)
        if not bool(possible.all()):
            i = int((~possible).nonzero()[0])
            raise ValueError(f"{cfg.demo.path}: {int((~possible).sum())} of {possible.numel()} pairs are not transitions "
                             f"of {cfg.env.env_id} under any action (first: pair {i}, {int(obs[i])} -> {int(nxt[i])}); "
                             "demos for another env, or shuffled next states")
    elif cfg.demo.form == "per_state":
        demos = tabular_state_pairs(model, policy)
    else:
        demos = tabular_trajectories(model, policy, cfg.demo.num_trajectories, cfg.env.max_episode_steps, generator)
    if cfg.demo.eta or cfg.demo.epsilon:
        demos = apply_demo_noise(
            demos, model, optimal, eta=cfg.demo.eta, epsilon=cfg.demo.epsilon,
            epsilon_mode=cfg.demo.epsilon_mode, generator=generator,
        )
    if cfg.demo.save_path:
        save_demos(demos, cfg.demo.save_path, {"env_id": cfg.env.env_id, "eta": cfg.demo.eta, "epsilon": cfg.demo.epsilon},
                   overwrite=cfg.overwrite)
    return demos, policy


def tabular_model(env_id: str) -> TabularModel:
    """The env's transition table, which the built-in expert (value iteration) and the
    demos need whatever ``env.backend`` steps the agent; a clear error where there is none
    or where transitions are random."""
    try:
        model = TabularModel.from_gym(env_id)
    except ValueError:
        raise ValueError(f"env.env_id={env_id}: this pipeline's built-in expert needs a toy-text env with a "
                         "transition table P (Taxi, CliffWalking, FrozenLake); env.backend does not change that") from None
    if not model.deterministic:
        raise ValueError(f"env.env_id={env_id}: its transitions are random (e.g. is_slippery); the built-in "
                         "expert and the expected-return evaluation need a deterministic env")
    return model


def train_taxi(cfg: TaxiConfig) -> dict[str, Any]:
    """Trains one agent on Taxi and writes ``metrics.csv``, ``summary.json``,
    ``learning_curve.png``, ``model.pt`` and a TorchRL trainer checkpoint (``checkpoint/``) into ``cfg.out_dir``. Returns the summary."""
    cfg.validate()
    logging.getLogger("torchrl").setLevel(logging.WARNING)
    # one progress-bar refresh per second (per 30 s when the output is a log file)
    os.environ.setdefault("TQDM_MININTERVAL", "1" if sys.stderr.isatty() else "30")
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    device = resolve_device(cfg.device)  # networks, learner, demos; the envs stay on the CPU
    variant = get_variant(cfg.variant)
    out = Path(cfg.out_dir)
    lock = prepare_out_dir(out, resume=cfg.resume, overwrite=cfg.overwrite)
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)

    model = tabular_model(cfg.env.env_id)
    S, A = model.n_states, model.n_actions
    demos, expert = make_taxi_demos(cfg, model, gen)

    env = make_toy_text_env(
        cfg.env.env_id, cfg.env.num_envs, backend=cfg.env.backend,
        max_episode_steps=cfg.env.max_episode_steps, seed=cfg.seed,
    )
    eval_env = make_toy_text_env(
        cfg.env.env_id, cfg.logger.eval_episodes, backend=cfg.env.backend,
        max_episode_steps=cfg.env.max_episode_steps, seed=cfg.seed + 10_000,
    )

    actor, critic = make_tabular_actor_critic(S, A, identity_embedding=cfg.identity_embedding)
    inverse_model = None
    if variant.inverse_model == "dual":
        inverse_model = DualInverseDynamics(
            OneHotEncoder(S), A, d_state=cfg.d_state, d=cfg.d, rank=cfg.rank,
            n_states=S if cfg.loss.idm_forward_coeff > 0 else None,
        )
    elif variant.inverse_model == "mlp":
        inverse_model = MLPInverseDynamics(OneHotEncoder(S), A, d_state=cfg.d_state, hidden=cfg.d, num_layers=cfg.mlp_layers)

    lc = cfg.loss
    loss = make_hybrid_loss(
        variant, actor, critic, inverse_model,
        gamma=lc.gamma, critic_coeff=lc.critic_coeff, entropy_coeff=lc.entropy_coeff,
        idm_action_coeff=lc.idm_action_coeff, idm_embedding_coeff=lc.idm_embedding_coeff,
        idm_forward_coeff=lc.idm_forward_coeff, bc_coeff=lc.bc_coeff, bc_labels=lc.bc_labels,
        bc_confidence=lc.bc_confidence, bc_entropy_floor=lc.bc_entropy_floor, expert_action_key=EXPERT_ACTION_KEY,
    ).to(device)
    optimizer = torch.optim.RMSprop(param_groups(loss), lr=cfg.optim.lr, eps=cfg.optim.eps, alpha=cfg.optim.alpha)

    collector = Collector(
        env, actor, frames_per_batch=cfg.frames_per_batch, total_frames=cfg.total_frames,
        env_device="cpu", policy_device=device, storing_device=device,
        auto_register_policy_transforms=False,  # a feed-forward policy needs none
    )
    logger = None
    if cfg.logger.backend != "none":
        logger = get_logger(cfg.logger.backend, logger_name=str(out / "logs"), experiment_name=f"{cfg.variant}_s{cfg.seed}")
    trainer = make_trainer(
        collector=collector, loss=loss, optimizer=optimizer, total_frames=cfg.total_frames,
        clip_norm=cfg.optim.max_grad_norm, logger=logger, progress_bar=cfg.logger.progress_bar,
        save_trainer_file=out / "checkpoint" if cfg.logger.checkpoint else None,
        save_trainer_interval=max(cfg.total_frames // 4, cfg.frames_per_batch),
        clip_per_group=cfg.optim.clip == "per_group",
    )

    if variant.bc is not None:
        sampler = {"visited": lambda: VisitedStateSampler(S), "uniform": lambda: None,
                   "curriculum": lambda: CurriculumSampler(cfg.demo.curriculum_k0, cfg.demo.curriculum_frames_per_step),
                   }[cfg.demo.rho]()
        attach_demonstrations(trainer, loss, demos, sampler=sampler, batch_size=cfg.demo.batch_size,
                              bc_coeff=lc.bc_coeff, bc_start_frames=lc.bc_start_frames,
                              bc_ready_accuracy=lc.bc_ready_accuracy,
                              include_expert_actions=variant.bc == "true", device=device)

    def evaluator(episodes_env=eval_env):
        returns = evaluate_policy(episodes_env, actor, cfg.env.max_episode_steps)
        row = {"eval_return": float(returns.mean())}
        if inverse_model is not None and EXPERT_ACTION_KEY in demos.keys():
            row["idm_accuracy"] = inverse_model_accuracy(inverse_model, demos)
        return row

    metrics = MetricsHook(out / "metrics.csv", cfg.logger.log_every_frames, evaluator, pbar_keys=("return_mean", "eval_return"))
    metrics.register(trainer)
    if isinstance(env.base_env, TabularEnv):  # bit-exact resume: random states, envs' states
        RunStateHook(collector, [env, eval_env]).register(trainer)
    resumed = resume_trainer(trainer, out, dataclasses.asdict(cfg), _RESUME_KEYS) if cfg.resume else 0
    (out / "config.json").write_text(json.dumps(dataclasses.asdict(cfg), indent=2))

    t0 = time.perf_counter()
    trainer.train()
    train_time = time.perf_counter() - t0

    final_env = make_toy_text_env(
        cfg.env.env_id, cfg.logger.final_eval_episodes, backend=cfg.env.backend,
        max_episode_steps=cfg.env.max_episode_steps, seed=cfg.seed + 20_000,
    )
    final_returns = evaluate_policy(final_env, actor, cfg.env.max_episode_steps)
    summary = {
        "variant": cfg.variant,
        "seed": cfg.seed,
        "frames": int(trainer.collected_frames),
        "final_return": float(final_returns.mean()),
        "final_return_std": float(final_returns.std()),
        "final_eval_episodes": int(final_returns.numel()),
        "optimal_return": expected_return(model, expert),
        "idm_accuracy": inverse_model_accuracy(inverse_model, demos)
        if inverse_model is not None and EXPERT_ACTION_KEY in demos.keys() else None,
        "train_time_s": round(train_time, 2),
        "frames_per_s": round((trainer.collected_frames - resumed) / train_time, 1),
        "resumed_from_frames": resumed,
        "config": dataclasses.asdict(cfg),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    torch.save(
        {"actor": actor.state_dict(), "critic": critic.state_dict(),
         "inverse_model": None if inverse_model is None else inverse_model.state_dict(),
         "config": dataclasses.asdict(cfg)},
        out / "model.pt",
    )
    plot_learning_curve(
        metrics.rows, out / "learning_curve.png",
        title=f"Taxi, {cfg.variant}, seed {cfg.seed}", optimal=summary["optimal_return"],
    )
    for e in (eval_env, final_env):
        e.close()
    lock.close()
    return summary
