"""Data collectors: :class:`AtariCollector`, a lean TorchRL collector for ale-py's vector
envs, and TorchRL's multi-process / Ray collectors over worker envs (:mod:`.workers`)."""

from torchrl_hybrid.collectors.atari import AtariCollector
from torchrl_hybrid.collectors.workers import WORKER_KINDS, BatchToDeviceHook, make_worker_collector

__all__ = ["AtariCollector", "BatchToDeviceHook", "WORKER_KINDS", "make_worker_collector"]
