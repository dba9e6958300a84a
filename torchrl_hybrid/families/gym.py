"""The gymnasium pipeline: Taxi (the paper's toy domain) and any other env with
discrete actions and either discrete states (toy-text: FrozenLake, CliffWalking) or
flat vector observations (CartPole): its configuration and :class:`GymFamily`, its
part of the one run assembly (:mod:`torchrl_hybrid.trainers.run`).

Discrete states get one-hot encoders, the authors' tabular actor and critic and a
built-in expert (value iteration on the env's ``P``). Vector observations get MLP
encoders, MLP actor and critic, and an expert given as a checkpoint (``model.pt`` of
an earlier run of this pipeline, e.g. ``variant=a2c``), whose trajectories are recorded
as the state-only demos.

``recipes/taxi.py`` and ``recipes/train.py`` are thin Hydra front-ends over
:func:`train_gym`; tests and notebooks call :func:`train_gym` directly with a
:class:`GymConfig`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any

import gymnasium
import torch
from torchrl.collectors import Collector

from torchrl_hybrid.collectors.workers import make_worker_collector, worker_devices
from torchrl_hybrid.data import (
    EXPERT_ACTION_KEY,
    CurriculumSampler,
    VisitedStateSampler,
    apply_demo_noise,
    check_observation_space,
    check_tabular_transitions,
    check_trajectories,
    load_demos,
    save_demos,
    tabular_state_pairs,
    tabular_trajectories,
)
from torchrl_hybrid.envs import BACKENDS, TabularEnv, TabularModel, make_gym_env, observation_kind
from torchrl_hybrid.experts import episode_ends, expected_return, load_gym_expert, optimal_policy, record_episodes
from torchrl_hybrid.modules import MLPEncoder, OneHotEncoder, make_mlp_actor_critic, make_tabular_actor_critic
from torchrl_hybrid.trainers.config import DemoConfig, LoggerConfig, RunConfig
from torchrl_hybrid.trainers.evaluation import evaluate_policy, inverse_model_accuracy
from torchrl_hybrid.trainers.hooks import RandomStateHook, RunStateHook
from torchrl_hybrid.trainers.run import EnvFamily, Networks, Run, Setup, build_run, train_run
from torchrl_hybrid.utils.config import MAX_FRAMES, check_float, check_int, check_types, dataclass_from_dict, require
from torchrl_hybrid.utils.device import resolve_device
from torchrl_hybrid.utils.metrics import IDM_ACCURACY_EXPERT
from torchrl_hybrid.variants import get_variant

# a checkpoint is resumed only by a run that agrees on these (total_frames may grow)
_RESUME_KEYS = (
    "variant",
    "seed",
    "rank",
    "d_state",
    "d",
    "mlp_layers",
    "identity_embedding",
    "env",
    "demo",
    "loss",
    "optim",
    "encoder",
    "rl",
    "ppo",
)

__all__ = [
    "GymConfig",
    "GymFamily",
    "config_from_dict",
    "make_taxi_demos",
    "build_gym",
    "train_gym",
    "record_episodes",
    "load_gym_expert",
]

RHOS = ("visited", "uniform", "curriculum")
EPSILON_MODES = ("non_optimal", "authors")
DEMO_FORMS = ("per_state", "trajectories")
ENGINES = ("torchrl", "batched")


# The settings below are the Hydra schema of recipes/config/taxi.yaml (torchrl_hybrid/configs.py):
# each default is written here once. Defaults follow the paper; where it is silent, the
# authors' public Taxi code (../shared/REFERENCE.md); choices neither source makes are marked OURS.


@dataclass
class EnvConfig:
    env_id: str = "Taxi-v4"  # gymnasium 1.4 name of Taxi; any toy-text env with a deterministic P, or CartPole-like
    # gym.make keyword arguments, added with a leading + on the command line, e.g. FrozenLake 8x8
    # without slipping: env.env_id=FrozenLake-v1 +env.kwargs.map_name=8x8 +env.kwargs.is_slippery=false
    kwargs: dict = field(default_factory=dict)
    num_envs: int = 16  # paper: 16 parallel environments
    # tabular = exact batched tensor copy of the env built from its transition table P (fast);
    # gym = gymnasium through TorchRL's GymEnv in a SerialEnv (any env); vector = one gymnasium
    # SyncVectorEnv behind TorchRL's GymWrapper; auto = tabular if the env has P, else vector
    backend: str = "auto"
    max_episode_steps: int = 50  # authors' code capped episodes at 50 steps (gymnasium's default for Taxi: 200)

    def validate(self) -> None:
        check_types(self, "env.")
        if ":" not in self.env_id:  # module:EnvId ids register on import, when gym.make imports the module
            try:
                gymnasium.spec(self.env_id)
            except gymnasium.error.Error as err:
                raise ValueError(
                    f"env.env_id={self.env_id}: {_one_line(err)} (gymnasium.pprint_registry() lists the "
                    "registered ids, e.g. Taxi-v4, FrozenLake-v1, CartPole-v1)"
                ) from None
        require(self.backend in BACKENDS, f"env.backend must be one of {BACKENDS}, got {self.backend!r}")
        check_int("env.num_envs", self.num_envs, 1)
        check_int("env.max_episode_steps", self.max_episode_steps, 1, MAX_FRAMES)


@dataclass
class GymDemoConfig(DemoConfig):
    # per_state = one expert pair (s, s') for each state (authors' code); trajectories = pairs from
    # num_trajectories expert episodes (the paper's general form). demo.path (a folder written by
    # torchrl_hybrid.data.save_demos) overrides both
    form: str = "per_state"
    num_trajectories: int = 100
    save_path: str | None = None  # write the demos this run uses (after noise) to this folder
    eta: float = 0.0  # fraction of states missing from the demos, in [0, 1)
    epsilon: float = 0.0  # fraction of demo transitions made by a non-optimal action, in [0, 1)
    # non_optimal = exactly floor(epsilon * pairs) pairs redrawn with a non-optimal action (this project's
    # spec); authors = each pair redrawn w.p. epsilon with a uniformly random move, as the authors' Taxi code
    epsilon_mode: str = "non_optimal"
    # discount of the built-in expert (value iteration on the env's P, ties to the lowest action); below 1
    # it takes the shortest way to the reward (with 1, FrozenLake's expert walks into a wall forever)
    expert_gamma: float = 0.99
    # vector observations: the expert played to record the demos: model.pt of an earlier run on this env, or
    # any callable policy as module:function (obs [n, d] -> n actions), e.g. a scripted controller:
    # torchrl_hybrid.experts.scripted:mountain_car_energy
    expert: str | None = None
    # a Minari dataset id (e.g. cartpole/expert-v0) in the local Minari cache: its state sequences are the
    # demos, its actions dropped on load (nothing is downloaded; torchrl_hybrid/data/minari.py)
    minari: str | None = None
    minari_path: str | None = None  # the local Minari cache (None: MINARI_DATASETS_PATH, else ~/.minari/datasets)
    deterministic: bool = True  # record the expert's greedy action (false: sample its policy)
    # rho, the distribution of expert pairs the BC term sees: visited = pairs at the states the agent
    # just visited (authors' Taxi code); uniform = batch_size pairs uniformly; curriculum = the paper's
    # Atari curriculum (curriculum_k0, curriculum_frames_per_step)
    rho: str = "visited"

    def validate(self, variant: str | None = None) -> None:
        super().validate(variant)
        require(self.form in DEMO_FORMS, f"demo.form must be one of {DEMO_FORMS}, got {self.form!r}")
        check_int("demo.num_trajectories", self.num_trajectories, 1)
        for name in ("eta", "epsilon"):
            check_float(f"demo.{name}", getattr(self, name), 0.0, 1.0, hi_open=True)
        require(
            self.epsilon_mode in EPSILON_MODES,
            f"demo.epsilon_mode must be one of {EPSILON_MODES}, got {self.epsilon_mode!r}",
        )
        # 0 would make the built-in expert indifferent to everything after the next reward
        check_float("demo.expert_gamma", self.expert_gamma, 0.0, 1.0, lo_open=True)
        require(self.rho in RHOS, f"demo.rho must be one of {RHOS}, got {self.rho!r}")


@dataclass
class GymLoggerConfig(LoggerConfig):
    eval_episodes: int = 100  # greedy episodes of every learning-curve row (eval_return)
    final_eval_episodes: int = 300  # greedy episodes of the final evaluation (summary.json's final_return)

    def validate(self) -> None:
        super().validate()
        check_int("logger.eval_episodes", self.eval_episodes, 1)
        check_int("logger.final_eval_episodes", self.final_eval_episodes, 1)


@dataclass
class CollectorConfig:
    """Where the agent's transitions are collected (:func:`make_collector`). env.num_envs is
    split evenly between the workers; the learner's weights reach them after every batch
    (TorchRL's UpdateWeights hook), so A2C stays synchronous."""

    kind: str = "single"  # single: TorchRL's Collector in this process | multi_sync: MultiSyncCollector,
    # `workers` processes | ray: RayCollector, `workers` Ray actors (pip install -e '.[ray]')
    workers: int = 2  # multi_sync / ray: env.num_envs is split evenly between them
    address: str | None = None  # ray: the cluster to join (e.g. auto); None starts a local one with `workers` CPUs
    # ray: the share of a GPU each actor asks for, to run its policy there; 0 = the workers run their policy
    # on the CPU (multi_sync workers always do) and each batch is moved to the learner's device
    worker_gpus: float = 0.0

    def validate(self) -> None:
        check_types(self, "collector.")
        require(self.kind in COLLECTORS, f"collector.kind must be one of {COLLECTORS}, got {self.kind!r}")
        check_int("collector.workers", self.workers, 1)
        check_float("collector.worker_gpus", self.worker_gpus, 0.0, cap=1024)
        worker_devices(self.kind, self.worker_gpus)  # worker_gpus: Ray only


COLLECTORS = ("single", "multi_sync", "ray")


@dataclass
class EncoderConfig:
    """Vector observations only: the MLP encoder (tanh) of the actor, critic and inverse model."""

    hidden: int = 64
    num_layers: int = 2

    def validate(self) -> None:
        check_types(self, "encoder.")
        check_int("encoder.hidden", self.hidden, 1)
        check_int("encoder.num_layers", self.num_layers, 1)


@dataclass
class GymConfig(RunConfig):
    """Every setting of a run of the gymnasium pipeline (Taxi by default), with its default;
    the Hydra schema of ``recipes/config/taxi.yaml``. The settings every run has
    (variant, seed, sizes, out_dir, device, resume, ...) and the shared loss, optim, logger and
    demo groups are in :mod:`torchrl_hybrid.trainers.run`; the defaults there are Taxi's
    (80,000 frames as in the paper's curves, rank 2)."""

    out_dir: str = "outputs/taxi"
    # authors' code: actor and critic start with a trainable S x S embedding set to the identity, then a
    # linear head; false = the paper's text, a single linear map of the one-hot state
    identity_embedding: bool = True
    # torchrl = TorchRL collector + Trainer with hooks (any env, every option, checkpoints);
    # batched = the sweep's fast path (families/gym_batched.py): same algorithm, tabular envs, CPU only,
    # rho=visited|uniform, no forward term, writes metrics/summary/plot but no checkpoint
    engine: str = "torchrl"
    env: EnvConfig = field(default_factory=EnvConfig)
    demo: GymDemoConfig = field(default_factory=GymDemoConfig)
    logger: GymLoggerConfig = field(default_factory=GymLoggerConfig)
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    collector: CollectorConfig = field(default_factory=CollectorConfig)

    def validate(self) -> GymConfig:
        """Raises ``ValueError`` naming the bad setting and what is allowed (one line), before
        anything is built: every setting's type and range, then the combinations."""
        get_variant(self.variant)
        check_types(self, recurse=False)
        require(self.engine in ENGINES, f"engine must be one of {ENGINES}, got {self.engine!r}")
        if self.engine == "batched" and self.resume:
            raise ValueError(
                "resume=true needs engine=torchrl (the batched engine writes no checkpoint); "
                "drop resume=true, or pass engine=torchrl"
            )
        if self.engine == "batched" and self.init_from:
            raise ValueError("init_from needs engine=torchrl (the batched engine starts from fresh weights)")
        if resolve_device(self.device).type != "cpu" and self.engine == "batched" and self.device != "auto":
            raise ValueError(
                f"engine=batched runs on the CPU only; use device=cpu (or device=auto), "
                f"or engine=torchrl for device={self.device}"
            )
        self.env.validate()
        self.collector.validate()
        self.encoder.validate()
        self.validate_run()  # the settings every family shares: sizes, seed, frames, demo, loss, optim, logger, ppo
        if self.collector.kind != "single":
            require(
                self.env.num_envs % self.collector.workers == 0,
                f"collector.workers={self.collector.workers} must divide env.num_envs={self.env.num_envs}",
            )
            require(self.engine == "torchrl", "collector.kind=multi_sync|ray needs engine=torchrl")
        envs_per_worker = self.env.num_envs // (self.collector.workers if self.collector.kind != "single" else 1)
        require(
            self.loss.explore_envs < envs_per_worker,
            f"loss.explore_envs={self.loss.explore_envs} must leave at least one env following the policy in each "
            f"collector ({envs_per_worker} envs each)",
        )
        require(
            self.rl == "a2c" or self.engine == "torchrl",
            f"rl={self.rl} needs engine=torchrl (the batched engine is the paper's A2C)",
        )
        require(
            self.total_frames >= self.frames_per_batch,
            f"total_frames={self.total_frames} is less than one batch (env.num_envs * loss.n_steps = {self.frames_per_batch})",
        )
        return self

    @property
    def frames_per_batch(self) -> int:
        return self.env.num_envs * self.loss.n_steps


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split())


def config_from_dict(d: dict[str, Any]) -> GymConfig:
    """Builds a :class:`GymConfig` from nested dicts (e.g. Hydra's), rejecting unknown keys."""
    return dataclass_from_dict(GymConfig, d)


def given_demos(cfg: GymConfig, obs_shape, obs_dtype):
    """The demos a run is given rather than records: ``demo.path`` (a folder written by
    ``save_demos``) or ``demo.minari`` (a local Minari dataset, actions dropped);
    ``None`` when neither is set. Demos recorded on another env are refused, and so are
    trajectories whose pairs do not chain and vector observations outside the env's
    observation space (:mod:`torchrl_hybrid.data.checks`)."""
    if cfg.demo.path and cfg.demo.minari:
        raise ValueError(f"demo.path={cfg.demo.path} and demo.minari={cfg.demo.minari}: choose one demo source")
    if cfg.demo.path:
        demos, meta = load_demos(cfg.demo.path, obs_shape=obs_shape, obs_dtype=obs_dtype)
        source = f"demo.path={cfg.demo.path}"
    elif cfg.demo.minari:
        from torchrl_hybrid.data.minari import load_minari_demos

        demos, meta = load_minari_demos(
            cfg.demo.minari, datasets_path=cfg.demo.minari_path, obs_shape=obs_shape, obs_dtype=obs_dtype
        )
        source = f"demo.minari={cfg.demo.minari}"
    else:
        return None
    if meta.get("env_id") not in (None, cfg.env.env_id):
        raise ValueError(f"{source}: demos are for {meta.get('env_id')}, this run plays {cfg.env.env_id}")
    fix = demo_fix(cfg)
    check_trajectories(demos, source, fix)
    if obs_dtype.is_floating_point:
        env = gymnasium.make(cfg.env.env_id, **cfg.env.kwargs)
        space = env.observation_space
        env.close()
        if isinstance(space, gymnasium.spaces.Box):
            check_observation_space(demos, space.low, space.high, source, fix, env_id=cfg.env.env_id)
    return demos


def demo_fix(cfg: GymConfig) -> str:
    """What to do about demos a check refuses (the end of its message)."""
    if cfg.demo.minari:
        return (
            "recreate the Minari dataset from the env's own episodes (minari.DataCollector), or record demos "
            "with demo.save_path=<folder>"
        )
    return (
        "re-record them: a run of recipes/train.py with demo.save_path=<folder> writes the demos it uses "
        "(the built-in expert's, or demo.expert=<model.pt>'s where the env has no table P)"
    )


def make_taxi_demos(cfg: GymConfig, model: TabularModel, generator: torch.Generator):
    """The demo pairs of a run: the optimal expert's (or a file's), then noise."""
    policy, optimal = optimal_policy(model, cfg.demo.expert_gamma)
    ends = episode_ends(model, policy, cfg.env.max_episode_steps)
    if not bool(ends.all()):
        raise ValueError(
            f"the built-in expert (value iteration, demo.expert_gamma={cfg.demo.expert_gamma}) does not end "
            f"an episode within env.max_episode_steps={cfg.env.max_episode_steps} from "
            f"{int((~ends).sum())} of {len(ends)} start states of {cfg.env.env_id}; raise "
            "env.max_episode_steps, or use demo.expert_gamma below 1 (0.99) so that it takes "
            "the shortest way to the goal"
        )
    demos = given_demos(cfg, obs_shape=(), obs_dtype=torch.long)
    source = cfg.demo.path or cfg.demo.minari
    if demos is not None:
        # every pair (s, s') must be a transition of the table P, and (s, a, s') where the true actions are stored
        check_tabular_transitions(
            demos, model, source, demo_fix(cfg), env_id=cfg.env.env_id, action_key=EXPERT_ACTION_KEY
        )
    elif cfg.demo.form == "per_state":
        demos = tabular_state_pairs(model, policy)
    else:
        demos = tabular_trajectories(model, policy, cfg.demo.num_trajectories, cfg.env.max_episode_steps, generator)
    if cfg.demo.eta or cfg.demo.epsilon:
        demos = apply_demo_noise(
            demos,
            model,
            optimal,
            eta=cfg.demo.eta,
            epsilon=cfg.demo.epsilon,
            epsilon_mode=cfg.demo.epsilon_mode,
            generator=generator,
        )
    if cfg.demo.save_path:
        save_demos(
            demos,
            cfg.demo.save_path,
            {"env_id": cfg.env.env_id, "eta": cfg.demo.eta, "epsilon": cfg.demo.epsilon},
            overwrite=cfg.overwrite,
        )
    return demos, policy


def tabular_model(env_id: str, env_kwargs: dict | None = None) -> TabularModel:
    """The env's transition table, which the built-in expert (value iteration) and the
    demos need whatever ``env.backend`` steps the agent; a clear error where there is none
    or where transitions are random."""
    try:
        model = TabularModel.from_gym(env_id, **dict(env_kwargs or {}))
    except ValueError:
        raise ValueError(
            f"env.env_id={env_id}: this pipeline's built-in expert needs a toy-text env with a "
            "transition table P (Taxi, CliffWalking, FrozenLake); env.backend does not change that"
        ) from None
    if not model.deterministic:
        raise ValueError(
            f"env.env_id={env_id}: its transitions are random (e.g. is_slippery); the built-in "
            "expert and the expected-return evaluation need a deterministic env"
        )
    return model


def _check_vector_config(cfg: GymConfig, needs_demos: bool = True) -> None:
    """Options that need a toy-text env's discrete states or its table P are refused
    for vector observations, with what to use instead."""
    env = cfg.env.env_id
    if cfg.env.backend == "tabular":
        raise ValueError(
            f"env.backend=tabular needs a toy-text env with a table P; {env} has vector observations: "
            "use env.backend=vector (or auto)"
        )
    if cfg.demo.rho == "visited":
        raise ValueError(
            f"demo.rho=visited matches expert pairs to visited discrete states; {env} has vector "
            "observations: use demo.rho=uniform or demo.rho=curriculum"
        )
    if cfg.demo.eta or cfg.demo.epsilon:
        raise ValueError(
            "demo.eta and demo.epsilon edit demos with the env's table P; for an env without one, "
            "record noisy demos yourself and pass demo.path"
        )
    if cfg.loss.idm_forward_coeff > 0:
        raise ValueError("loss.idm_forward_coeff > 0 (the forward head P_f over next states) needs discrete states")
    if cfg.engine == "batched":
        raise ValueError("engine=batched runs toy-text envs only; use engine=torchrl for vector observations")
    if needs_demos and not cfg.demo.expert and not cfg.demo.path and not cfg.demo.minari:
        raise ValueError(
            f"{env} has no table P, so there is no built-in expert: train one with this pipeline "
            f"(variant=a2c out_dir=<dir>) and pass demo.expert=<dir>/model.pt, or pass recorded demos "
            "with demo.path=<folder> or a local Minari dataset with demo.minari=<dataset id>"
        )


def make_gym_demos(cfg: GymConfig, expert_actor, size: int):
    """State-only demos of a vector-observation env (observations of ``size``):
    ``demo.path`` or ``demo.minari`` if given, else ``demo.num_trajectories`` whole episodes of
    ``expert_actor`` (greedy unless ``demo.deterministic=false``), the true actions kept
    for diagnostics only."""
    demos = given_demos(cfg, obs_shape=(size,), obs_dtype=torch.float32)
    if demos is not None:
        return demos
    demos, returns = record_episodes(
        cfg.env.env_id,
        expert_actor,
        cfg.demo.num_trajectories,
        cfg.env.max_episode_steps,
        seed=cfg.seed + 30_000,
        env_kwargs=cfg.env.kwargs,
        deterministic=cfg.demo.deterministic,
    )
    if cfg.demo.save_path:
        save_demos(
            demos,
            cfg.demo.save_path,
            {"env_id": cfg.env.env_id, "expert": cfg.demo.expert, "returns": returns.tolist()},
            overwrite=cfg.overwrite,
        )
    return demos


def _worker_env(cfg: GymConfig, i: int):
    """The envs of collector worker ``i``: its share of ``env.num_envs``, its own seed."""
    return make_gym_env(
        cfg.env.env_id,
        cfg.env.num_envs // cfg.collector.workers,
        backend=cfg.env.backend,
        max_episode_steps=cfg.env.max_episode_steps,
        seed=cfg.seed + 1000 * i,
        env_kwargs=cfg.env.kwargs,
    )


def make_collector(cfg: GymConfig, env, actor, device):
    """TorchRL's collector for ``cfg.collector.kind``: ``Collector`` over ``env`` in this
    process (the default), or ``MultiSyncCollector`` / ``RayCollector`` over
    ``collector.workers`` workers, each stepping ``env.num_envs / workers`` envs with its
    own copy of the policy (kept current by TorchRL's weight update, see ``UpdateWeights``).
    Every kind gives batches of ``env.num_envs x loss.n_steps`` transitions; the workers'
    kinds are synchronous (each batch is collected with the weights of the last update)."""
    common = dict(frames_per_batch=cfg.frames_per_batch, total_frames=cfg.total_frames)
    if cfg.collector.kind == "single":
        return Collector(
            env,
            actor,
            env_device="cpu",
            policy_device=device,
            storing_device=device,
            auto_register_policy_transforms=False,  # a feed-forward policy needs none
            **common,
        )
    env.close()  # the workers build their own envs
    fns = [functools.partial(_worker_env, cfg, i) for i in range(cfg.collector.workers)]
    return make_worker_collector(
        cfg.collector.kind, fns, actor, address=cfg.collector.address, worker_gpus=cfg.collector.worker_gpus, **common
    )


@dataclass
class GymSetup(Setup):
    """The gym family's :class:`Setup`: what its later steps need."""

    kind: str = "discrete"  # observation_kind(): "discrete" (tabular) or "vector"
    size: int = 0  # the observation's length (vector) or the state count (discrete)
    eval_env: Any = None  # the greedy evaluation's envs (logger.eval_episodes of them)
    model: TabularModel | None = None  # tabular envs: the transition table
    expert: Any = None  # tabular envs: the built-in optimal policy
    expert_actor: Any = None  # vector envs: the expert (a checkpoint's actor or a callable), None without one


class GymFamily(EnvFamily):
    """The gymnasium envs of this pipeline in the one run assembly
    (:func:`~torchrl_hybrid.trainers.run.build_run`): toy-text envs get one-hot encoders,
    the authors' tabular actor and critic and the built-in expert; vector observations get
    MLP encoders and an expert checkpoint."""

    name = "gym"
    resume_keys = _RESUME_KEYS
    init_keys = ("env.env_id", "env.kwargs", "encoder")
    checkpoints_per_run = 4
    pbar_keys = ("return_mean", "eval_return")

    def setup(self, cfg: GymConfig, variant, device, generator) -> GymSetup:
        try:
            kind, size, A = observation_kind(cfg.env.env_id, cfg.env.kwargs)
        except (gymnasium.error.Error, ModuleNotFoundError, TypeError) as err:  # unknown id or module, bad kwargs
            raise ValueError(
                f"env.env_id={cfg.env.env_id} with env.kwargs={cfg.env.kwargs}: gymnasium cannot make "
                f"it ({type(err).__name__}: {_one_line(err)}); check the id and its keyword arguments"
            ) from None
        model = expert = expert_actor = n_states = demos = None
        if kind == "discrete":
            model = tabular_model(cfg.env.env_id, cfg.env.kwargs)
            A, n_states = model.n_actions, model.n_states
            demos, expert = make_taxi_demos(cfg, model, generator)
        else:  # vector observations: the expert is a checkpoint (or its recorded demos); plain A2C needs neither
            needs_demos = variant.bc is not None or variant.inverse_model is not None
            _check_vector_config(cfg, needs_demos)
            expert_actor = load_gym_expert(cfg, size, A)
            demos = make_gym_demos(cfg, expert_actor, size) if needs_demos else None
        env = self.make_env(cfg, cfg.env.num_envs, cfg.seed)
        eval_env = self.make_env(cfg, cfg.logger.eval_episodes, cfg.seed + 10_000)
        return GymSetup(env, A, demos, n_states, kind, size, eval_env, model, expert, expert_actor)

    @staticmethod
    def make_env(cfg: GymConfig, num_envs: int, seed: int):
        return make_gym_env(
            cfg.env.env_id,
            num_envs,
            backend=cfg.env.backend,
            max_episode_steps=cfg.env.max_episode_steps,
            seed=seed,
            env_kwargs=cfg.env.kwargs,
        )

    def networks(self, cfg: GymConfig, variant, setup: GymSetup) -> Networks:
        A = setup.n_actions
        if setup.kind == "discrete":
            S = setup.n_states
            actor, critic = make_tabular_actor_critic(S, A, identity_embedding=cfg.identity_embedding)
            return Networks(actor, critic, lambda: OneHotEncoder(S))  # the inverse model's own e_s
        size, enc = setup.size, cfg.encoder
        actor, critic = make_mlp_actor_critic(size, A, enc.hidden, enc.num_layers)
        return Networks(actor, critic, lambda: MLPEncoder(size, enc.hidden, enc.num_layers))

    def collector(self, cfg: GymConfig, setup: GymSetup, policy, device, total_steps: int):
        return make_collector(cfg, setup.env, policy, device)

    def small_model(self, cfg: GymConfig) -> bool:
        return True  # one-hot tables and small MLPs: device=auto keeps them on the CPU

    def uses_workers(self, cfg: GymConfig) -> bool:
        return cfg.collector.kind != "single"

    def sampler(self, cfg: GymConfig, setup: GymSetup):
        if cfg.demo.rho == "visited":
            return VisitedStateSampler(setup.n_states)
        if cfg.demo.rho == "curriculum":
            return CurriculumSampler(cfg.demo.curriculum_k0, cfg.demo.curriculum_frames_per_step)
        return None

    def evaluator(self, run: Run):
        cfg, demos, inverse_model, actor = run.cfg, run.demos, run.inverse_model, run.actor
        eval_env = run.setup.eval_env
        labelled = demos is not None and EXPERT_ACTION_KEY in demos.keys()

        def evaluate():
            row = {"eval_return": float(evaluate_policy(eval_env, actor, cfg.env.max_episode_steps).mean())}
            if inverse_model is not None:  # NaN where the demos carry no true actions
                row[IDM_ACCURACY_EXPERT] = inverse_model_accuracy(inverse_model, demos) if labelled else math.nan
            return row

        return evaluate

    def register_late_hooks(self, run: Run) -> None:
        if run.cfg.collector.kind == "single" and isinstance(run.env.base_env, TabularEnv):
            # bit-exact resume: random states, the envs' states
            RunStateHook(run.collector, [run.env, run.setup.eval_env]).register(run.trainer)
        else:  # gymnasium envs cannot save their state; the random state still resumes
            RandomStateHook().register(run.trainer)

    def finish(self, run: Run) -> tuple[dict, dict]:
        cfg, x, max_steps = run.cfg, run.setup, run.cfg.env.max_episode_steps
        final_env = self.make_env(cfg, cfg.logger.final_eval_episodes, cfg.seed + 20_000)
        final_returns = evaluate_policy(final_env, run.actor, max_steps)
        final_env.close()
        # the expert's own return, never assumed: exact from the start distribution for the built-in
        # expert; for an expert checkpoint its greedy return on the same final episodes (None without one)
        optimal_return = None
        if x.model is not None:
            optimal_return = expected_return(x.model, x.expert, max_steps)
        elif x.expert_actor is not None:
            expert_env = self.make_env(cfg, cfg.logger.final_eval_episodes, cfg.seed + 20_000)
            optimal_return = float(evaluate_policy(expert_env, x.expert_actor, max_steps).mean())
            expert_env.close()
        labelled = run.demos is not None and EXPERT_ACTION_KEY in run.demos.keys()
        return {
            "final_return": float(final_returns.mean()),
            "final_return_std": float(final_returns.std()),
            "final_eval_episodes": int(final_returns.numel()),
            "optimal_return": optimal_return,
            IDM_ACCURACY_EXPERT: inverse_model_accuracy(run.inverse_model, run.demos)
            if run.inverse_model is not None and labelled
            else None,
        }, {}

    def title(self, cfg: GymConfig) -> str:
        return f"{cfg.env.env_id}, {cfg.variant}, seed {cfg.seed}"

    def plot_kwargs(self, run: Run, summary: dict) -> dict:
        return {"optimal": summary["optimal_return"]}

    def close(self, setup: GymSetup) -> None:
        setup.eval_env.close()


def build_gym(cfg: GymConfig) -> Run:
    """Builds one run of the gymnasium pipeline without training it: ``build_gym(cfg).trainer.train()``."""
    return build_run(cfg, GymFamily())


def train_gym(cfg: GymConfig) -> dict[str, Any]:
    """Trains one agent on ``cfg.env`` (Taxi by default; any env with discrete actions and
    discrete states or vector observations) and writes ``metrics.csv``, ``summary.json``,
    ``learning_curve.png``, ``model.pt`` and a TorchRL trainer checkpoint (``checkpoint/``)
    into ``cfg.out_dir``. Returns the summary."""
    return train_run(cfg, GymFamily())
