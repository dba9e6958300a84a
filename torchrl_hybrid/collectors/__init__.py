"""Data collectors: :class:`AtariCollector`, a lean TorchRL collector for ale-py's vector envs."""
from torchrl_hybrid.collectors.atari import AtariCollector

__all__ = ["AtariCollector"]
