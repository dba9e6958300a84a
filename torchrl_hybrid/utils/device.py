"""The ``device`` setting: ``auto`` | ``cpu`` | ``cuda`` (``cuda:N``)."""
from __future__ import annotations

import torch

__all__ = ["module_device", "resolve_device"]


def resolve_device(device: str | torch.device | None = "auto") -> torch.device:
    """``"auto"`` (or ``None``) is CUDA when available, else the CPU; ``"cuda"``
    without a usable GPU is an error that says so, never a silent CPU fallback."""
    if isinstance(device, torch.device):
        device = str(device)
    name = "auto" if device is None else str(device).strip().lower()
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(name)
    except (RuntimeError, ValueError):
        raise ValueError(f"device={device!r}: choose auto, cpu or cuda (cuda:N for a given GPU)") from None
    if dev.type not in ("cpu", "cuda"):
        raise ValueError(f"device={device!r}: choose auto, cpu or cuda (cuda:N for a given GPU)")
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"device={device!r} but PyTorch sees no CUDA GPU (torch {torch.__version__}); "
                             "use device=cpu or device=auto")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ValueError(f"device={device!r} but only {torch.cuda.device_count()} CUDA GPU(s) are visible")
    return dev


def module_device(module) -> torch.device:
    """Where a module's parameters are (the CPU for a module without any)."""
    p = next(iter(module.parameters()), None)
    return p.device if p is not None else torch.device("cpu")
