"""Collection in several worker processes or Ray actors, with TorchRL's own collectors.

Each worker builds its envs from its own function (its share of the envs, its own seed)
and holds a copy of the policy; :class:`torchrl.trainers.UpdateWeights` (registered by the
pipelines) pushes the learner's weights to every worker after each batch, so the data of a
batch always comes from the weights of the last update (synchronous A2C).

Devices: the workers run their policy and store their batches on the CPU, whatever the
learner's device (a worker process or Ray actor has no GPU of its own: Ray hides the GPUs
from actors that do not ask for them). A learner on a GPU hands TorchRL a CPU copy of its
policy (:func:`worker_policy`) and pushes its weights to the workers after every batch
(:func:`worker_weights_getter`, one device-to-host copy of the weights per batch); the
batches are moved to the learner's device when they arrive (:class:`BatchToDeviceHook`).
With Ray, ``worker_gpus > 0`` asks for that share of a GPU per actor instead, and the
actors run their policy there.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.collectors import MultiSyncCollector
from torchrl.trainers import Trainer, TrainerHookBase

__all__ = [
    "WORKER_KINDS",
    "BatchToDeviceHook",
    "make_worker_collector",
    "worker_devices",
    "worker_policy",
    "worker_weights_getter",
]

WORKER_KINDS = ("multi_sync", "ray")


def worker_devices(kind: str, worker_gpus: float = 0.0) -> dict[str, str]:
    """Where the workers of ``kind`` keep their envs, run their policy and store their batches."""
    if worker_gpus < 0:
        raise ValueError(f"collector.worker_gpus={worker_gpus} must be >= 0")
    if worker_gpus > 0 and kind != "ray":
        raise ValueError(
            f"collector.worker_gpus={worker_gpus} is a Ray setting (the GPU share of each Ray actor); "
            f"{kind!r} collection does not use it"
        )
    dev = "cuda" if worker_gpus > 0 else "cpu"
    return {"env_device": "cpu", "policy_device": dev, "storing_device": dev}


def _on_cpu(policy) -> bool:
    return all(p.device.type == "cpu" for p in policy.parameters())


def worker_policy(policy):
    """The policy TorchRL copies into the workers: ``policy`` itself when it is on the CPU,
    else a CPU copy (the learner's weights reach the workers through
    :func:`worker_weights_getter`)."""
    return policy if _on_cpu(policy) else copy.deepcopy(policy).to("cpu")


def worker_weights_getter(policy) -> Callable[[], TensorDictBase] | None:
    """For TorchRL's ``UpdateWeights(policy_weights_getter=...)``: the learner's current
    weights on the CPU, or ``None`` when the learner's policy is on the CPU (TorchRL then reads
    the collector's own policy, which is the learner's)."""
    if _on_cpu(policy):
        return None
    from tensordict import TensorDict

    return lambda: TensorDict.from_module(policy).data.to("cpu")


def make_worker_collector(
    kind: str,
    env_fns: Sequence[Callable],
    policy,
    *,
    frames_per_batch: int,
    total_frames: int,
    address: str | None = None,
    worker_gpus: float = 0.0,
):
    """``MultiSyncCollector`` (``kind="multi_sync"``: one process per env function) or
    ``RayCollector`` (``kind="ray"``: one Ray actor per env function, on the cluster at
    ``address``, or on a local one with ``len(env_fns)`` CPUs started here). The workers run
    the policy on the CPU, or, for Ray with ``worker_gpus > 0``, on that share of a GPU each
    (:func:`worker_devices`); a policy on a GPU is copied to the CPU for them
    (:func:`worker_policy`). Register a :class:`BatchToDeviceHook` to bring the batches to the
    learner's device, and TorchRL's ``UpdateWeights`` with :func:`worker_weights_getter` to
    keep the workers' weights current."""
    devices = worker_devices(kind, worker_gpus)
    policy = worker_policy(policy)
    if kind == "multi_sync":
        return MultiSyncCollector(
            list(env_fns),
            policy,
            frames_per_batch=frames_per_batch,
            total_frames=total_frames,
            cat_results=0,
            auto_register_policy_transforms=False,
            **devices,
        )
    if kind != "ray":
        raise ValueError(f"unknown worker collector {kind!r}; choose one of {WORKER_KINDS}")
    from torchrl_hybrid.utils.launch import init_ray

    init_ray(address, num_cpus=len(env_fns))
    from torchrl.collectors.distributed import RayCollector

    remote = {"num_cpus": 1, **({"num_gpus": worker_gpus} if worker_gpus > 0 else {})}
    return RayCollector(
        list(env_fns),
        policy,
        frames_per_batch=frames_per_batch,
        total_frames=total_frames,
        sync=True,
        remote_configs=remote,
        collector_kwargs={"auto_register_policy_transforms": False},
        **devices,
    )


class BatchToDeviceHook(TrainerHookBase):
    """Moves each collected batch to the learner's ``device`` (``batch_process``), for
    collectors whose workers store their batches elsewhere. A batch already there is
    returned as it is."""

    def __init__(self, device: str | torch.device):
        self.device = torch.device(device)

    def __call__(self, batch: TensorDictBase) -> TensorDictBase:
        return batch if batch.device == self.device else batch.to(self.device, non_blocking=True)

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        return

    def register(self, trainer: Trainer, name: str = "batch_to_device") -> None:
        trainer.register_op("batch_process", self)
