"""Collection in several worker processes or Ray actors, with TorchRL's own collectors.

Each worker builds its envs from its own function (its share of the envs, its own seed)
and holds a copy of the policy; :class:`torchrl.trainers.UpdateWeights` (registered by the
pipelines) pushes the learner's weights to every worker after each batch, so the data of a
batch always comes from the weights of the last update (synchronous A2C).
"""
from __future__ import annotations

from typing import Callable, Sequence

import torch
from torchrl.collectors import MultiSyncCollector

__all__ = ["WORKER_KINDS", "make_worker_collector"]

WORKER_KINDS = ("multi_sync", "ray")


def make_worker_collector(kind: str, env_fns: Sequence[Callable], policy, *, frames_per_batch: int,
                          total_frames: int, device: torch.device, address: str | None = None):
    """``MultiSyncCollector`` (``kind="multi_sync"``: one process per env function) or
    ``RayCollector`` (``kind="ray"``: one Ray actor per env function, on the cluster at
    ``address``, or on a local one with ``len(env_fns)`` CPUs started here). Batches are
    stored on ``device``; the workers run the policy on the CPU."""
    if kind == "multi_sync":
        return MultiSyncCollector(list(env_fns), policy, frames_per_batch=frames_per_batch, total_frames=total_frames,
                                  env_device="cpu", policy_device="cpu", storing_device=device, cat_results=0,
                                  auto_register_policy_transforms=False)
    if kind != "ray":
        raise ValueError(f"unknown worker collector {kind!r}; choose one of {WORKER_KINDS}")
    from torchrl_hybrid.utils.launch import init_ray

    init_ray(address, num_cpus=len(env_fns))
    from torchrl.collectors.distributed import RayCollector

    return RayCollector(list(env_fns), policy, frames_per_batch=frames_per_batch, total_frames=total_frames, sync=True,
                        remote_configs={"num_cpus": 1}, storing_device=device,
                        collector_kwargs={"auto_register_policy_transforms": False})
