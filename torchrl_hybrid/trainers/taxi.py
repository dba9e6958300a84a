"""The gymnasium pipeline: Taxi (the paper's toy domain) and any other env with
discrete actions and either discrete states (toy-text: FrozenLake, CliffWalking) or
flat vector observations (CartPole): configuration, assembly and one training run.

Discrete states get one-hot encoders, the authors' tabular actor and critic and a
built-in expert (value iteration on the env's ``P``). Vector observations get MLP
encoders, MLP actor and critic, and an expert given as a checkpoint (``model.pt`` of
an earlier run of this pipeline, e.g. ``variant=a2c``), whose trajectories are recorded
as the state-only demos.

``recipes/taxi.py`` and ``recipes/train.py`` are thin Hydra front-ends over
:func:`train_taxi`; tests and notebooks call :func:`train_taxi` directly with a
:class:`TaxiConfig`.
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
from torchrl.collectors import Collector
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.record.loggers import get_logger
from torchrl.trainers import UpdateWeights

from torchrl_hybrid.collectors.workers import make_worker_collector
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
from torchrl_hybrid.envs import BACKENDS, TabularEnv, TabularModel, make_toy_text_env, observation_kind
from torchrl_hybrid.experts import episode_ends, expected_return, optimal_policy
from torchrl_hybrid.modules import (
    DualInverseDynamics,
    MLPEncoder,
    MLPInverseDynamics,
    OneHotEncoder,
    make_mlp_actor_critic,
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
                "optim", "encoder")
from torchrl_hybrid.utils.config import dataclass_from_dict
from torchrl_hybrid.utils.device import resolve_device
from torchrl_hybrid.utils.files import prepare_out_dir
from torchrl_hybrid.utils.metrics import IDM_ACCURACY_EXPERT
from torchrl_hybrid.utils.plotting import plot_learning_curve

__all__ = ["TaxiConfig", "config_from_dict", "make_taxi_demos", "train_taxi"]

RHOS = ("visited", "uniform", "curriculum")
DEMO_FORMS = ("per_state", "trajectories")
LOGGERS = ("csv", "tensorboard", "wandb", "none")
ENGINES = ("torchrl", "batched")


@dataclass
class EnvConfig:
    env_id: str = "Taxi-v4"
    kwargs: dict = field(default_factory=dict)  # gym.make keyword arguments, e.g. map_name, is_slippery
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
    expert_gamma: float = 0.99  # discount of the built-in value-iteration expert (below 1: shortest way to the reward)
    expert: str | None = None   # vector observations: model.pt of an earlier run on this env, played to record demos
    deterministic: bool = True  # record the expert's greedy action (false: sample its policy)
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
class CollectorConfig:
    """Where the agent's transitions are collected (torchrl_hybrid/trainers/taxi.py: make_collector)."""

    kind: str = "single"         # single: TorchRL's Collector in this process | multi_sync: MultiSyncCollector,
                                 # `workers` processes | ray: RayCollector, `workers` Ray actors
    workers: int = 2             # multi_sync / ray: env.num_envs is split evenly between them
    address: str | None = None   # ray: the cluster to join; None starts a local one with `workers` CPUs


COLLECTORS = ("single", "multi_sync", "ray")


@dataclass
class EncoderConfig:
    """Vector observations only: the MLP encoder of the actor, critic and inverse model."""

    hidden: int = 64
    num_layers: int = 2


@dataclass
class TaxiConfig:
    """Every knob of a run of the gymnasium pipeline (Taxi by default); ``recipes/config/taxi.yaml``
    documents each one."""

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
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    collector: CollectorConfig = field(default_factory=CollectorConfig)

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
        need(self.collector.kind in COLLECTORS, f"collector.kind must be one of {COLLECTORS}, got {self.collector.kind!r}")
        if self.collector.kind != "single":
            need(self.collector.workers >= 1 and self.env.num_envs % self.collector.workers == 0,
                 f"collector.workers={self.collector.workers} must divide env.num_envs={self.env.num_envs}")
            need(self.engine == "torchrl", "collector.kind=multi_sync|ray needs engine=torchrl")
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
    policy, optimal = optimal_policy(model, cfg.demo.expert_gamma)
    ends = episode_ends(model, policy, cfg.env.max_episode_steps)
    if not bool(ends.all()):
        raise ValueError(f"the built-in expert (value iteration, demo.expert_gamma={cfg.demo.expert_gamma}) does not end "
                         f"an episode within env.max_episode_steps={cfg.env.max_episode_steps} from "
                         f"{int((~ends).sum())} of {len(ends)} start states of {cfg.env.env_id}; raise "
                         "env.max_episode_steps, or use demo.expert_gamma below 1 (0.99) so that it takes "
                         "the shortest way to the goal")
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


def tabular_model(env_id: str, env_kwargs: dict | None = None) -> TabularModel:
    """The env's transition table, which the built-in expert (value iteration) and the
    demos need whatever ``env.backend`` steps the agent; a clear error where there is none
    or where transitions are random."""
    try:
        model = TabularModel.from_gym(env_id, **dict(env_kwargs or {}))
    except ValueError:
        raise ValueError(f"env.env_id={env_id}: this pipeline's built-in expert needs a toy-text env with a "
                         "transition table P (Taxi, CliffWalking, FrozenLake); env.backend does not change that") from None
    if not model.deterministic:
        raise ValueError(f"env.env_id={env_id}: its transitions are random (e.g. is_slippery); the built-in "
                         "expert and the expected-return evaluation need a deterministic env")
    return model


def _check_vector_config(cfg: TaxiConfig, needs_demos: bool = True) -> None:
    """Options that need a toy-text env's discrete states or its table P are refused
    for vector observations, with what to use instead."""
    env = cfg.env.env_id
    if cfg.env.backend == "tabular":
        raise ValueError(f"env.backend=tabular needs a toy-text env with a table P; {env} has vector observations: "
                         "use env.backend=vector (or auto)")
    if cfg.demo.rho == "visited":
        raise ValueError(f"demo.rho=visited matches expert pairs to visited discrete states; {env} has vector "
                         "observations: use demo.rho=uniform or demo.rho=curriculum")
    if cfg.demo.eta or cfg.demo.epsilon:
        raise ValueError("demo.eta and demo.epsilon edit demos with the env's table P; for an env without one, "
                         "record noisy demos yourself and pass demo.path")
    if cfg.loss.idm_forward_coeff > 0:
        raise ValueError("loss.idm_forward_coeff > 0 (the forward head P_f over next states) needs discrete states")
    if cfg.engine == "batched":
        raise ValueError("engine=batched runs toy-text envs only; use engine=torchrl for vector observations")
    if needs_demos and not cfg.demo.expert and not cfg.demo.path:
        raise ValueError(f"{env} has no table P, so there is no built-in expert: train one with this pipeline "
                         f"(variant=a2c out_dir=<dir>) and pass demo.expert=<dir>/model.pt, or pass recorded demos "
                         "with demo.path=<folder>")


def load_gym_expert(cfg: TaxiConfig, size: int, n_actions: int):
    """The expert policy of a vector-observation env (observations of ``size``): the actor
    of ``cfg.demo.expert`` (``model.pt`` of an earlier run of this pipeline on the same
    env), rebuilt from the settings stored beside its weights; ``None`` without one."""
    if not cfg.demo.expert:  # demos given as a file: the expert is only needed for its evaluation
        return None
    path = Path(cfg.demo.expert)
    if not path.is_file():
        raise FileNotFoundError(f"demo.expert={path}: no such checkpoint; train an expert first "
                                f"(variant=a2c out_dir=<dir>) and pass <dir>/model.pt")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
        saved, actor_state, enc = ckpt["config"], ckpt["actor"], ckpt["config"]["encoder"]
    except Exception as err:  # not a model.pt of this pipeline
        raise ValueError(f"demo.expert={path} is not a model.pt written by this pipeline ({err})") from err
    if saved["env"]["env_id"] != cfg.env.env_id or saved["env"].get("kwargs", {}) != cfg.env.kwargs:
        raise ValueError(f"demo.expert={path} was trained on {saved['env']['env_id']} {saved['env'].get('kwargs', {})}, "
                         f"this run plays {cfg.env.env_id} {cfg.env.kwargs}")
    actor, _ = make_mlp_actor_critic(size, n_actions, enc["hidden"], enc["num_layers"])
    actor.load_state_dict(actor_state)
    return actor.eval()


def make_gym_demos(cfg: TaxiConfig, expert_actor, size: int):
    """State-only demos of a vector-observation env (observations of ``size``):
    ``demo.path`` if given, else ``demo.num_trajectories`` whole episodes of
    ``expert_actor`` (greedy unless ``demo.deterministic=false``), the true actions kept
    for diagnostics only."""
    if cfg.demo.path:
        demos, meta = load_demos(cfg.demo.path, obs_shape=(size,), obs_dtype=torch.float32)
        if meta.get("env_id", cfg.env.env_id) != cfg.env.env_id:
            raise ValueError(f"demo.path={cfg.demo.path}: demos are for {meta.get('env_id')}, this run plays "
                             f"{cfg.env.env_id}")
        return demos
    demos, returns = record_episodes(cfg.env.env_id, expert_actor, cfg.demo.num_trajectories,
                                     cfg.env.max_episode_steps, seed=cfg.seed + 30_000, env_kwargs=cfg.env.kwargs,
                                     deterministic=cfg.demo.deterministic)
    if cfg.demo.save_path:
        save_demos(demos, cfg.demo.save_path, {"env_id": cfg.env.env_id, "expert": cfg.demo.expert,
                                               "returns": returns.tolist()}, overwrite=cfg.overwrite)
    return demos


@torch.no_grad()
def record_episodes(env_id: str, policy, num_episodes: int, max_steps: int, *, seed: int = 0,
                    env_kwargs: dict | None = None, deterministic: bool = True, num_envs: int = 16):
    """Plays ``num_episodes`` whole episodes of ``policy`` and returns them as expert
    pairs (:func:`~torchrl_hybrid.data.pairs_from_trajectories`: ``step`` and
    ``trajectory`` indices, the true actions under ``expert_action``) and the
    ``[num_episodes]`` episode returns."""
    from torchrl_hybrid.data import pairs_from_trajectories

    states, actions, returns = [], [], []
    etype = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    round_ = 0
    while len(states) < num_episodes:
        n = min(num_envs, num_episodes - len(states))
        env = make_toy_text_env(env_id, n, max_episode_steps=max_steps, seed=seed + 1000 * round_,
                                env_kwargs=env_kwargs)
        with set_exploration_type(etype):
            td = env.rollout(max_steps, policy, break_when_any_done=False)
        env.close()
        done = td.get(("next", "done")).squeeze(-1)
        if not done.any(-1).all():
            raise RuntimeError(f"an expert episode did not end within {max_steps} steps; raise env.max_episode_steps")
        for i in range(n):
            end = int(done[i].nonzero()[0])  # the first episode of env i: steps 0..end
            states.append(torch.cat([td["observation"][i, : end + 1], td["next", "observation"][i, end: end + 1]]))
            actions.append(td["action"][i, : end + 1])
            returns.append(float(td["next", "reward"][i, : end + 1].sum()))
        round_ += 1
    return pairs_from_trajectories(states, actions), torch.tensor(returns)


def _worker_env(cfg: TaxiConfig, i: int):
    """The envs of collector worker ``i``: its share of ``env.num_envs``, its own seed."""
    return make_toy_text_env(cfg.env.env_id, cfg.env.num_envs // cfg.collector.workers, backend=cfg.env.backend,
                             max_episode_steps=cfg.env.max_episode_steps, seed=cfg.seed + 1000 * i,
                             env_kwargs=cfg.env.kwargs)


def make_collector(cfg: TaxiConfig, env, actor, device):
    """TorchRL's collector for ``cfg.collector.kind``: ``Collector`` over ``env`` in this
    process (the default), or ``MultiSyncCollector`` / ``RayCollector`` over
    ``collector.workers`` workers, each stepping ``env.num_envs / workers`` envs with its
    own copy of the policy (kept current by TorchRL's weight update, see ``UpdateWeights``).
    Every kind gives batches of ``env.num_envs x loss.n_steps`` transitions; the workers'
    kinds are synchronous (each batch is collected with the weights of the last update)."""
    common = dict(frames_per_batch=cfg.frames_per_batch, total_frames=cfg.total_frames)
    if cfg.collector.kind == "single":
        return Collector(env, actor, env_device="cpu", policy_device=device, storing_device=device,
                         auto_register_policy_transforms=False,  # a feed-forward policy needs none
                         **common)
    env.close()  # the workers build their own envs
    fns = [functools.partial(_worker_env, cfg, i) for i in range(cfg.collector.workers)]
    return make_worker_collector(cfg.collector.kind, fns, actor, device=device, address=cfg.collector.address, **common)


def train_taxi(cfg: TaxiConfig) -> dict[str, Any]:
    """Trains one agent on ``cfg.env`` (Taxi by default; any env with discrete actions and
    discrete states or vector observations) and writes ``metrics.csv``, ``summary.json``,
    ``learning_curve.png``, ``model.pt`` and a TorchRL trainer checkpoint (``checkpoint/``)
    into ``cfg.out_dir``. Returns the summary."""
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

    kind, size, A = observation_kind(cfg.env.env_id, cfg.env.kwargs)
    model = expert_actor = None
    if kind == "discrete":
        model = tabular_model(cfg.env.env_id, cfg.env.kwargs)
        S, A = model.n_states, model.n_actions
        demos, expert = make_taxi_demos(cfg, model, gen)
    else:  # vector observations: the expert is a checkpoint (or its recorded demos); plain A2C needs neither
        needs_demos = variant.bc is not None or variant.inverse_model is not None
        _check_vector_config(cfg, needs_demos)
        expert_actor = load_gym_expert(cfg, size, A)
        demos = make_gym_demos(cfg, expert_actor, size) if needs_demos else None

    env = make_toy_text_env(
        cfg.env.env_id, cfg.env.num_envs, backend=cfg.env.backend,
        max_episode_steps=cfg.env.max_episode_steps, seed=cfg.seed, env_kwargs=cfg.env.kwargs,
    )
    eval_env = make_toy_text_env(
        cfg.env.env_id, cfg.logger.eval_episodes, backend=cfg.env.backend,
        max_episode_steps=cfg.env.max_episode_steps, seed=cfg.seed + 10_000, env_kwargs=cfg.env.kwargs,
    )

    if kind == "discrete":
        actor, critic = make_tabular_actor_critic(S, A, identity_embedding=cfg.identity_embedding)
    else:
        actor, critic = make_mlp_actor_critic(size, A, cfg.encoder.hidden, cfg.encoder.num_layers)

    def state_encoder():  # the inverse model's own e_s (the actor and critic keep theirs)
        return OneHotEncoder(S) if kind == "discrete" else MLPEncoder(size, cfg.encoder.hidden, cfg.encoder.num_layers)

    inverse_model = None
    if variant.inverse_model == "dual":
        inverse_model = DualInverseDynamics(
            state_encoder(), A, d_state=cfg.d_state, d=cfg.d, rank=cfg.rank,
            n_states=S if cfg.loss.idm_forward_coeff > 0 else None,
        )
    elif variant.inverse_model == "mlp":
        inverse_model = MLPInverseDynamics(state_encoder(), A, d_state=cfg.d_state, hidden=cfg.d,
                                           num_layers=cfg.mlp_layers)

    lc = cfg.loss
    loss = make_hybrid_loss(
        variant, actor, critic, inverse_model,
        gamma=lc.gamma, critic_coeff=lc.critic_coeff, entropy_coeff=lc.entropy_coeff,
        idm_action_coeff=lc.idm_action_coeff, idm_embedding_coeff=lc.idm_embedding_coeff,
        idm_forward_coeff=lc.idm_forward_coeff, bc_coeff=lc.bc_coeff, bc_labels=lc.bc_labels,
        bc_confidence=lc.bc_confidence, bc_entropy_floor=lc.bc_entropy_floor, expert_action_key=EXPERT_ACTION_KEY,
    ).to(device)
    optimizer = torch.optim.RMSprop(param_groups(loss), lr=cfg.optim.lr, eps=cfg.optim.eps, alpha=cfg.optim.alpha)

    collector = make_collector(cfg, env, actor, device)
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

    labelled = demos is not None and EXPERT_ACTION_KEY in demos.keys()

    def evaluator(episodes_env=eval_env):
        returns = evaluate_policy(episodes_env, actor, cfg.env.max_episode_steps)
        row = {"eval_return": float(returns.mean())}
        if inverse_model is not None:  # NaN where the demos carry no true actions
            row[IDM_ACCURACY_EXPERT] = inverse_model_accuracy(inverse_model, demos) if labelled else math.nan
        return row

    metrics = MetricsHook(out / "metrics.csv", cfg.logger.log_every_frames, evaluator, pbar_keys=("return_mean", "eval_return"))
    metrics.register(trainer)
    if cfg.collector.kind == "single" and isinstance(env.base_env, TabularEnv):
        RunStateHook(collector, [env, eval_env]).register(trainer)  # bit-exact resume: random states, envs' states
    if cfg.collector.kind != "single":  # the workers' policy copies get the learner's weights after every batch
        UpdateWeights(collector, update_weights_interval=1).register(trainer)
    resumed = resume_trainer(trainer, out, dataclasses.asdict(cfg), _RESUME_KEYS) if cfg.resume else 0
    (out / "config.json").write_text(json.dumps(dataclasses.asdict(cfg), indent=2))

    t0 = time.perf_counter()
    trainer.train()
    train_time = time.perf_counter() - t0

    final_env = make_toy_text_env(
        cfg.env.env_id, cfg.logger.final_eval_episodes, backend=cfg.env.backend,
        max_episode_steps=cfg.env.max_episode_steps, seed=cfg.seed + 20_000, env_kwargs=cfg.env.kwargs,
    )
    final_returns = evaluate_policy(final_env, actor, cfg.env.max_episode_steps)
    # the expert's own return, never assumed: exact from the start distribution for the built-in
    # expert; for an expert checkpoint its greedy return on the same final episodes (None without one)
    optimal_return = None
    if model is not None:
        optimal_return = expected_return(model, expert, cfg.env.max_episode_steps)
    elif expert_actor is not None:
        expert_env = make_toy_text_env(cfg.env.env_id, cfg.logger.final_eval_episodes, backend=cfg.env.backend,
                                       max_episode_steps=cfg.env.max_episode_steps, seed=cfg.seed + 20_000,
                                       env_kwargs=cfg.env.kwargs)
        optimal_return = float(evaluate_policy(expert_env, expert_actor, cfg.env.max_episode_steps).mean())
        expert_env.close()
    summary = {
        "variant": cfg.variant,
        "seed": cfg.seed,
        "frames": int(trainer.collected_frames),
        "final_return": float(final_returns.mean()),
        "final_return_std": float(final_returns.std()),
        "final_eval_episodes": int(final_returns.numel()),
        "optimal_return": optimal_return,
        IDM_ACCURACY_EXPERT: inverse_model_accuracy(inverse_model, demos)
        if inverse_model is not None and labelled else None,
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
    if cfg.collector.kind != "single":
        collector.shutdown()
    lock.close()
    return summary
