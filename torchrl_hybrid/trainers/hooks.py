"""TorchRL trainer hooks that add the hybrid agent's behaviour to ``Trainer``."""

from __future__ import annotations

import csv
import math
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import ReplayBuffer
from torchrl.objectives import LossModule
from torchrl.trainers import Trainer, TrainerHookBase

__all__ = [
    "ExpertBatchHook",
    "CurriculumHook",
    "DelayedCoefficientHook",
    "InverseModelReadyHook",
    "MetricsHook",
    "MinibatchHook",
    "NextStateValueHook",
    "RandomStateHook",
    "RunStateHook",
    "LRWarmupHook",
    "random_state",
    "set_random_state",
]


def _check_schedulable(loss: LossModule, name: str) -> None:
    """A hook sets ``loss.<name> = value``; that updates the buffer in place only for
    the loss's ``_schedulable_buffers`` (TorchRL's convention), so others are refused."""
    if not isinstance(getattr(loss, name, None), torch.Tensor):
        raise ValueError(f"{type(loss).__name__} has no coefficient buffer {name!r}")
    if name not in getattr(type(loss), "_all_schedulable_buffers", ()):
        raise ValueError(
            f"{type(loss).__name__}.{name} is not one of its _schedulable_buffers "
            f"({sorted(getattr(type(loss), '_all_schedulable_buffers', ()))}); declare it there "
            "so that assigning a float updates the buffer in place"
        )


class ExpertBatchHook(TrainerHookBase):
    """Pairs every optimisation batch with a batch of expert state pairs.

    Registered at ``process_optim_batch``: the collected batch becomes
    ``TensorDict({agent_key: batch, expert_key: expert_batch}, [])``, the input
    :class:`~torchrl_hybrid.objectives.HybridLoss` reads. If the buffer's sampler
    has an ``observe`` method (e.g. :class:`~torchrl_hybrid.data.VisitedStateSampler`),
    it is first shown the agent's states of the batch.

    Args:
        expert_buffer: replay buffer of expert pairs.
        batch_size: expert pairs per optimisation step.
        state_key: the agent's state entry shown to ``observe``.
    """

    def __init__(
        self,
        expert_buffer: ReplayBuffer,
        batch_size: int,
        *,
        agent_key: str = "agent",
        expert_key: str = "expert",
        state_key="observation",
    ):
        self.expert_buffer = expert_buffer
        self.batch_size = batch_size
        self.agent_key, self.expert_key, self.state_key = agent_key, expert_key, state_key

    def __call__(self, batch: TensorDictBase) -> TensorDictBase:
        sampler = self.expert_buffer.sampler
        if hasattr(sampler, "observe"):
            sampler.observe(batch.get(self.state_key))
        expert = self.expert_buffer.sample(self.batch_size)
        return TensorDict({self.agent_key: batch, self.expert_key: expert}, [])

    def state_dict(self) -> dict[str, Any]:
        return {"sampler": self.expert_buffer.sampler.state_dict()}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.expert_buffer.sampler.load_state_dict(state_dict["sampler"])

    def register(self, trainer: Trainer, name: str = "expert_batch") -> None:
        trainer.register_op("process_optim_batch", self)
        trainer.register_module(name, self)


class CurriculumHook(TrainerHookBase):
    """Tells a :class:`~torchrl_hybrid.data.CurriculumSampler` how many frames have
    been collected, after every collection (``post_steps``)."""

    def __init__(self, sampler):
        self.sampler = sampler
        self._trainer: Trainer | None = None

    def __call__(self) -> None:
        self.sampler.update(self._trainer.collected_frames)

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        return

    def register(self, trainer: Trainer, name: str = "curriculum") -> None:
        self._trainer = trainer
        trainer.register_op("post_steps", self)


def _annealed(value: float, frames_on: int, anneal_frames: int) -> float:
    """``value`` after ``frames_on`` frames switched on: constant with ``anneal_frames=0``,
    else falling linearly to 0 over ``anneal_frames``."""
    return value if anneal_frames == 0 else value * max(0.0, 1.0 - frames_on / anneal_frames)


class DelayedCoefficientHook(TrainerHookBase):
    """Keeps a loss coefficient at 0 until ``start_frames`` frames were collected,
    then sets it to ``value`` (the paper uses the BC term only after 100k frames);
    with ``anneal_frames > 0`` it then falls linearly to 0 over that many frames
    (OURS: BC weight annealing, so that the RL signal takes over once the agent no
    longer needs the inferred labels; 0 = the paper's constant weight).

    Args:
        loss: the loss module that owns the coefficient buffer.
        name: the buffer's name, e.g. ``"bc_coeff"``.
        value: the coefficient once switched on.
        start_frames: frames before switching on.
        anneal_frames: frames over which it then decays to 0 (0: it stays at ``value``).
    """

    def __init__(self, loss: LossModule, name: str, value: float, start_frames: int, anneal_frames: int = 0):
        _check_schedulable(loss, name)
        if anneal_frames < 0:
            raise ValueError(f"anneal_frames must be >= 0, got {anneal_frames}")
        self.loss, self.name, self.value, self.start_frames = loss, name, float(value), int(start_frames)
        self.anneal_frames = int(anneal_frames)
        self._trainer: Trainer | None = None
        self._set(self.at(0))

    def at(self, frames: int) -> float:
        """The coefficient after ``frames`` collected frames."""
        return (
            0.0 if frames < self.start_frames else _annealed(self.value, frames - self.start_frames, self.anneal_frames)
        )

    def _set(self, value: float) -> None:
        setattr(self.loss, self.name, value)  # a schedulable buffer: updated in place

    def __call__(self) -> None:
        self._set(self.at(self._trainer.collected_frames))

    def state_dict(self) -> dict[str, Any]:
        return {"current": float(getattr(self.loss, self.name))}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        if "current" in state_dict:  # a resumed run continues with the coefficient it had
            self._set(float(state_dict["current"]))

    def register(self, trainer: Trainer, name: str = "delayed_coeff") -> None:
        self._trainer = trainer
        trainer.register_op("post_steps", self)
        trainer.register_module(name, self)


class LRWarmupHook(TrainerHookBase):
    """Raises every optimiser group's learning rate linearly from 0 to its value over the
    first ``warmup_frames`` collected frames, then leaves it there.

    Why: a fresh RMSprop (or Adam without bias correction) divides the first gradients by
    the root of a nearly empty square average, so its first updates are up to 10x ``lr``.
    From random weights that does little harm; from trained ones (``init_from``, training an
    expert longer) it knocks the policy off (the Pong 10M expert fell from +8 to -20 in its
    first 80k frames without it). Stateless: a resumed run recomputes the rate from its
    collected frames.

    Args:
        optimizer: the optimiser whose groups' ``lr`` are scaled (their values when the hook
            is built are the targets).
        warmup_frames: frames over which the rate rises (> 0).
    """

    def __init__(self, optimizer: torch.optim.Optimizer, warmup_frames: int):
        if warmup_frames <= 0:
            raise ValueError(f"warmup_frames must be > 0, got {warmup_frames}")
        self.optimizer, self.warmup_frames = optimizer, int(warmup_frames)
        self.base_lrs = [float(g["lr"]) for g in optimizer.param_groups]
        self._trainer: Trainer | None = None

    def scale(self, frames: int) -> float:
        """The factor on each group's ``lr`` once ``frames`` frames were collected."""
        return min(1.0, max(frames, 0) / self.warmup_frames)

    def __call__(self) -> None:
        f = self.scale(self._trainer.collected_frames)  # frames including the batch about to be used
        for g, lr in zip(self.optimizer.param_groups, self.base_lrs):
            g["lr"] = lr * f

    def register(self, trainer: Trainer, name: str = "lr_warmup") -> None:
        self._trainer = trainer
        trainer.register_op("pre_optim_steps", self)


class InverseModelReadyHook(TrainerHookBase):
    """Keeps a loss coefficient (the BC term's) at 0 until the inverse model is ready,
    then sets it to ``value`` for good, or, with ``anneal_frames > 0``, lets it fall
    linearly from ``value`` to 0 over that many frames after the switch-on.

    Ready means: the running mean (exponential, weight ``smoothing`` on the newest
    batch) of the inverse model's accuracy on the agent's own transitions reaches
    ``accuracy``, and at least ``min_frames`` frames were collected. That accuracy is
    ``idm_accuracy`` of the inverse-dynamics loss, computed on each batch before the
    update that trains on it (so held out) against the agent's own actions: no
    expert label is read.

    Args:
        loss: the loss module that owns the coefficient buffer.
        name: the buffer's name, e.g. ``"bc_coeff"``.
        value: the coefficient once switched on.
        accuracy: the running accuracy to reach.
        min_frames: frames before switching on, whatever the accuracy.
        smoothing: weight of the newest batch in the running mean.
        accuracy_key: the loss output holding the batch accuracy.
        anneal_frames: frames over which the coefficient falls from ``value`` to 0 once
            switched on (0: it stays at ``value``).
    """

    def __init__(
        self,
        loss: LossModule,
        name: str,
        value: float,
        accuracy: float,
        *,
        min_frames: int = 0,
        smoothing: float = 0.05,
        accuracy_key: str = "idm_accuracy",
        anneal_frames: int = 0,
    ):
        _check_schedulable(loss, name)
        if not 0.0 < accuracy <= 1.0:
            raise ValueError(f"accuracy={accuracy} must be in (0, 1]")
        if anneal_frames < 0:
            raise ValueError(f"anneal_frames must be >= 0, got {anneal_frames}")
        self.loss, self.name, self.value = loss, name, float(value)
        self.accuracy, self.min_frames, self.smoothing, self.accuracy_key = (
            float(accuracy),
            int(min_frames),
            float(smoothing),
            accuracy_key,
        )
        self.anneal_frames = int(anneal_frames)
        self.running: float | None = None
        self.on_at: int | None = None  # frames when it switched on
        self._trainer: Trainer | None = None
        setattr(self.loss, self.name, 0.0)

    def at(self, frames: int) -> float:
        """The coefficient after ``frames`` collected frames (0 until switched on)."""
        if self.on_at is None or frames < self.on_at:
            return 0.0
        return _annealed(self.value, frames - self.on_at, self.anneal_frames)

    def __call__(self, optim_steps: int, average_losses: TensorDictBase | None) -> dict[str, Any] | None:
        frames = int(self._trainer.collected_frames)
        if self.on_at is None and average_losses is not None and self.accuracy_key in average_losses.keys():
            acc = float(average_losses.get(self.accuracy_key))
            self.running = acc if self.running is None else (1 - self.smoothing) * self.running + self.smoothing * acc
            if self.running >= self.accuracy and frames >= self.min_frames:
                self.on_at = frames
        setattr(self.loss, self.name, self.at(frames))
        return None

    def state_dict(self) -> dict[str, Any]:
        return {
            "running": -1.0 if self.running is None else self.running,
            "on_at": -1 if self.on_at is None else self.on_at,
        }

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        running, on_at = float(state_dict["running"]), int(state_dict["on_at"])
        self.running = None if running < 0 else running
        self.on_at = None if on_at < 0 else on_at
        frames = self.on_at if self._trainer is None else int(self._trainer.collected_frames)
        setattr(self.loss, self.name, self.at(frames))

    def register(self, trainer: Trainer, name: str = "inverse_model_ready") -> None:
        self._trainer = trainer
        trainer.register_op("post_optim_complete_log", self)
        trainer.register_module(name, self)


class MetricsHook(TrainerHookBase):
    """Writes the learning curve: one CSV row every ``every_frames`` frames.

    Each row has ``frames``, ``return_mean`` (mean undiscounted return of the
    training episodes that ended since the previous row), ``episodes``, the
    trainer's averaged losses and diagnostics of the last optimisation step,
    ``time_s``, and whatever ``evaluator()`` returns (e.g. a greedy evaluation
    return, the inverse model's accuracy on the demos). Rows also go to the
    trainer's TorchRL logger and the progress bar.

    Args:
        csv_path: where to write the CSV.
        every_frames: frames between rows.
        evaluator: callable returning a dict of extra scalar columns.
        pbar_keys: columns shown in the progress bar.
        return_key: the batch entry holding each episode's running return
            (TorchRL's ``RewardSum`` writes ``("next", "episode_reward")``).
    """

    def __init__(
        self,
        csv_path: str | Path,
        every_frames: int,
        evaluator: Callable[[], dict[str, float]] | None = None,
        pbar_keys: tuple[str, ...] = ("return_mean",),
        return_key=("next", "episode_reward"),
    ):
        self.csv_path = Path(csv_path)
        self.every_frames = int(every_frames)
        self.evaluator = evaluator
        self.pbar_keys = pbar_keys
        self.return_key = return_key
        self.rows: list[dict[str, float]] = []
        self._returns: list[tuple[torch.Tensor, torch.Tensor]] = []  # (running returns, done) per batch
        self._losses: dict[str, torch.Tensor] = {}
        self._next = 0
        self._t0 = time.perf_counter()
        self._trainer: Trainer | None = None
        self._fieldnames: list[str] | None = None

    def collect(self, batch: TensorDictBase) -> None:
        # kept on the learner's device until the next row: no device-to-host sync per batch (copies:
        # a collector may write its next batch into the same memory)
        done = batch.get(("next", "done")).reshape(-1).clone()
        if "explore" in batch.keys():  # the explorer slots' random-action episodes are not the agent's
            done &= ~batch.get("explore").reshape(-1)
        self._returns.append((batch.get(self.return_key).reshape(-1).clone(), done))

    def losses(self, optim_steps: int, average_losses: TensorDictBase | None) -> None:
        if average_losses is not None:  # read on the host only when a row is written
            self._losses = {k: v.detach() for k, v in average_losses.items() if v.numel() == 1}

    def row(self) -> dict[str, float]:
        """Computes and writes one row now (the device-to-host reads of the row happen here,
        once per row, not once per update)."""
        if self._returns:
            returns = torch.cat([r for r, _ in self._returns])[torch.cat([d for _, d in self._returns])]
        else:
            returns = torch.zeros(0)
        self._returns = []
        row = {
            "frames": int(self._trainer.collected_frames) if self._trainer else 0,
            "return_mean": float(returns.mean()) if returns.numel() else math.nan,
            "episodes": int(returns.numel()),
        }
        if self._losses:  # one read for every loss and diagnostic of the last update
            names = list(self._losses)
            dev = next(iter(self._losses.values())).device
            # float32 -> float64 is exact: the same numbers as float() of each tensor
            values = torch.stack([self._losses[k].reshape(()).to(dev, torch.float64) for k in names]).tolist()
            row.update(zip(names, values))
        if self.evaluator is not None:
            extra = self.evaluator()
            clash = sorted(set(extra) & set(self._losses))
            if clash:  # one meaning per column: an evaluation must not overwrite a loss diagnostic
                raise ValueError(f"the evaluator's columns {clash} are also loss outputs; give them other names")
            row.update(extra)
        row["time_s"] = round(time.perf_counter() - self._t0, 3)
        self._write(row)
        return row

    def _write(self, row: dict[str, float]) -> None:
        self.rows.append(row)
        new = self._fieldnames is None
        if new:
            self._fieldnames = list(row.keys())
            self.csv_path.parent.mkdir(parents=True, exist_ok=True)
        with self.csv_path.open("w" if new else "a", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=self._fieldnames, extrasaction="ignore", restval="")
            if new:
                writer.writeheader()
            writer.writerow(row)

    def __call__(self, batch: TensorDictBase) -> dict[str, Any] | None:
        self.collect(batch)
        frames = self._trainer.collected_frames
        if frames < self._next and frames < self._trainer.total_frames:
            return None
        self._next = frames + self.every_frames
        row = self.row()
        logger = self._trainer.logger
        if logger is not None:
            for k, v in row.items():
                if k != "frames" and isinstance(v, (int, float)) and math.isfinite(v):
                    logger.log_scalar(f"curve/{k}", v, step=frames)
        shown = {k: row[k] for k in self.pbar_keys if k in row and math.isfinite(row[k])}
        return {**shown, "log_pbar": True} if shown else None

    def state_dict(self) -> dict[str, Any]:
        return {"next": self._next, "rows": len(self.rows), "elapsed": time.perf_counter() - self._t0}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Resumes the curve: keeps the CSV's first ``rows`` rows (those written
        before the checkpoint) and appends after them; ``time_s`` goes on counting."""
        self._next = state_dict["next"]
        self._t0 = time.perf_counter() - float(state_dict.get("elapsed", 0.0))
        n = int(state_dict.get("rows", 0))
        rows, fieldnames = [], None
        if self.csv_path.exists():
            with self.csv_path.open(newline="") as f:
                reader = csv.DictReader(f)
                fieldnames = reader.fieldnames
                for r in reader:
                    rows.append(
                        {
                            k: (int(v) if k in ("frames", "episodes") else float(v))
                            for k, v in r.items()
                            if v not in ("", None)
                        }
                    )
        if len(rows) < n:
            warnings.warn(
                f"{self.csv_path} holds {len(rows)} rows but the checkpoint was taken after {n}; "
                "the resumed curve misses the rest",
                stacklevel=2,
            )
        self.rows = rows[:n]
        self._fieldnames = fieldnames if self.rows else None
        if self.rows:  # drop rows logged after the checkpoint: they will be logged again
            with self.csv_path.open("w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=fieldnames, extrasaction="ignore", restval="")
                writer.writeheader()
                writer.writerows(self.rows)

    def register(self, trainer: Trainer, name: str = "metrics") -> None:
        self._trainer = trainer
        trainer.register_op("post_optim_complete_log", self.losses)
        trainer.register_op("post_steps_log", self)
        trainer.register_module(name, self)


class NextStateValueHook(TrainerHookBase):
    """Completes a collected batch with ``("next", "state_value")`` so that the RL
    loss's value estimator (built with ``skip_existing=True``) need not run the
    critic on the whole batch again.

    The collection policy already wrote ``state_value`` for every step with the
    current parameters (one optimiser step per batch keeps them current). The value
    of a step's next state is the next step's stored value, except after the last
    step and where the episode ended (the next observation is then the old
    episode's last one): only those are computed here.

    Args:
        critic: the value network (reads ``observation``, writes ``state_value``).
    """

    def __init__(self, critic, value_key: str = "state_value"):
        self.critic, self.value_key = critic, value_key

    @torch.no_grad()
    def __call__(self, batch: TensorDictBase) -> TensorDictBase:
        if batch.ndim > 2:  # [workers, envs, time] from a stacking multi-worker collector (RayCollector)
            batch = batch.reshape(-1, batch.shape[-1])
        if batch.ndim != 2:
            raise ValueError(f"NextStateValueHook expects a [envs, time] batch, got batch size {tuple(batch.shape)}")
        v = batch.get(self.value_key)
        nv = torch.empty_like(v)
        nv[:, :-1] = v[:, 1:]
        need = batch.get(("next", "done")).reshape(batch.shape).clone()
        need[:, -1] = True
        rows = need.reshape(-1).nonzero().squeeze(-1)  # one device-to-host sync: how many values to compute
        obs = batch.get(("next", "observation")).flatten(0, 1)[rows]
        values = self.critic(TensorDict({"observation": obs}, [obs.shape[0]])).get(self.value_key)
        nv.view(-1, *nv.shape[2:])[rows] = values
        batch.set(("next", self.value_key), nv)
        return batch

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        return

    def register(self, trainer: Trainer, name: str = "next_state_value") -> None:
        trainer.register_op("batch_process", self)


class MinibatchHook(TrainerHookBase):
    """PPO's epochs of minibatches over each collected batch, in TorchRL's trainer.

    At ``batch_process`` the RL loss's value estimator (GAE) writes ``advantage`` and
    ``value_target`` on the whole ``[envs, time]`` batch, once, without gradient, and the
    batch is flattened. At ``process_optim_batch`` (register it before the
    :class:`ExpertBatchHook`, which then pairs each minibatch with expert pairs) each of the
    trainer's ``epochs x minibatches`` optimisation steps gets the next minibatch of a fresh
    random permutation per epoch.

    Args:
        value_estimator: e.g. ``ClipPPOLoss.value_estimator`` (TorchRL's GAE).
        minibatches: minibatches per epoch; they must divide the batch.
    """

    def __init__(self, value_estimator, minibatches: int):
        if minibatches < 1:
            raise ValueError(f"minibatches must be >= 1, got {minibatches}")
        self.value_estimator, self.minibatches = value_estimator, int(minibatches)
        self._flat: TensorDictBase | None = None
        self._perm: torch.Tensor | None = None
        self._step = 0

    @torch.no_grad()
    def process(self, batch: TensorDictBase) -> TensorDictBase:
        batch = self.value_estimator(batch)
        self._flat, self._step = batch.reshape(-1), 0
        if self._flat.shape[0] % self.minibatches:
            raise ValueError(
                f"a batch of {self._flat.shape[0]} transitions does not split into {self.minibatches} "
                "minibatches; choose ppo.minibatches dividing env.num_envs * loss.n_steps"
            )
        return batch

    def __call__(self, batch: TensorDictBase) -> TensorDictBase:
        n = self._flat.shape[0]
        k = self._step % self.minibatches
        if k == 0:  # a new epoch: a new order
            self._perm = torch.randperm(n, device=self._flat.device)
        self._step += 1
        size = n // self.minibatches
        return self._flat[self._perm[k * size : (k + 1) * size]]

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        return

    def register(self, trainer: Trainer, name: str = "minibatches") -> None:
        trainer.register_op("batch_process", self.process)
        trainer.register_op("process_optim_batch", self)


def random_state() -> dict[str, Any]:
    """torch's global random state: the CPU generator's and, where CUDA is in use, every
    CUDA device's (what ``torch.manual_seed`` seeds, so what a resumed run must restore)."""
    state: dict[str, Any] = {"torch_rng": torch.get_rng_state()}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda_rng"] = torch.stack(torch.cuda.get_rng_state_all())
    return state


def set_random_state(state: dict[str, Any]) -> None:
    """Restores :func:`random_state`. A state saved with CUDA generators restores them when
    as many CUDA devices are visible; on a machine without them (a CUDA run resumed on the
    CPU) only the CPU generator is restored, with a warning: the run goes on, not
    bit-exactly."""
    torch.set_rng_state(torch.as_tensor(state["torch_rng"], dtype=torch.uint8).cpu())
    cuda = state.get("cuda_rng")
    if cuda is None:
        return
    cuda = [torch.as_tensor(c, dtype=torch.uint8).cpu() for c in cuda]
    if torch.cuda.is_available() and torch.cuda.device_count() == len(cuda):
        torch.cuda.set_rng_state_all(cuda)
    else:
        warnings.warn(
            f"the checkpoint holds the random state of {len(cuda)} CUDA device(s), this machine has "
            f"{torch.cuda.device_count() if torch.cuda.is_available() else 0}; only the CPU generator is "
            "restored, so the resumed run is not bit-exact",
            stacklevel=2,
        )


class RandomStateHook(TrainerHookBase):
    """Checkpoints torch's global random state (CPU and CUDA generators: :func:`random_state`),
    so that a resumed run draws the same actions, expert batches and noise as one that never
    stopped. :class:`RunStateHook` includes it."""

    def state_dict(self) -> dict[str, Any]:
        return random_state()

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        set_random_state(state_dict)

    def register(self, trainer: Trainer, name: str = "random_state") -> None:
        trainer.register_module(name, self)


class RunStateHook(TrainerHookBase):
    """Checkpoints what a bit-exact resume needs beyond weights, optimiser and samplers:
    torch's global random state (CPU and CUDA generators), the collector's carried-over
    tensordict (the envs' current observations and running returns) and the envs' own
    state, for envs that offer ``run_state`` / ``load_run_state``
    (:class:`~torchrl_hybrid.envs.TabularEnv`, also under a ``TransformedEnv``).

    Args:
        collector: a TorchRL ``Collector`` (its ``_carrier`` is the carried-over tensordict).
        envs: the envs whose state is saved: the training env, and e.g. an evaluation env.
    """

    def __init__(self, collector, envs):
        self.collector = collector
        self.envs = [getattr(e, "base_env", e) for e in envs]
        missing = [type(e).__name__ for e in self.envs if not hasattr(e, "run_state")]
        if missing:
            raise ValueError(f"RunStateHook: {missing} cannot save their state (no run_state())")

    def state_dict(self) -> dict[str, Any]:
        carrier = getattr(self.collector, "_carrier", None)
        return {
            **random_state(),
            "carrier": None if carrier is None else carrier.to_dict(),
            "envs": {str(i): e.run_state() for i, e in enumerate(self.envs)},
        }

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        set_random_state(state_dict)
        carrier = getattr(self.collector, "_carrier", None)
        if carrier is not None and state_dict.get("carrier") is not None:
            carrier.update(TensorDict(state_dict["carrier"], batch_size=carrier.batch_size, device=carrier.device))
        for i, e in enumerate(self.envs):
            e.load_run_state({k: torch.as_tensor(v) for k, v in state_dict["envs"][str(i)].items()})

    def register(self, trainer: Trainer, name: str = "run_state") -> None:
        trainer.register_module(name, self)
