"""The ``device`` setting: ``auto`` | ``cpu`` | ``cuda`` (``cuda:N``)."""

from __future__ import annotations

import torch

__all__ = ["module_device", "resolve_device", "accelerator_available"]

# set by torchrl_hybrid.testing.DeviceRuleCheck while it runs: "cuda" then resolves to this
# stand-in device (a CPU-backed device with CUDA's rules), so the CUDA code paths run without a GPU
_STAND_IN: torch.device | None = None


def accelerator_available() -> bool:
    """Whether ``device=cuda`` can run here (a CUDA GPU, or the device-rule stand-in)."""
    return _STAND_IN is not None or torch.cuda.is_available()


def resolve_device(device: str | torch.device | None = "auto", *, small_model: bool = False) -> torch.device:
    """The device a run's networks, learner and demos live on.

    ``"auto"`` (or ``None``) is CUDA when available, else the CPU; with
    ``small_model=True`` (tabular and small-MLP networks, where every env step would
    cost a host-device round trip larger than the network's work) ``"auto"`` is the CPU.
    ``"cuda"`` without a usable GPU is an error that says so, never a silent CPU
    fallback."""
    if isinstance(device, torch.device):
        device = str(device)
    name = "auto" if device is None else str(device).strip().lower()
    if name == "auto":
        if small_model or not accelerator_available():
            return torch.device("cpu")
        return _STAND_IN if _STAND_IN is not None else torch.device("cuda")
    try:
        dev = torch.device(name)
    except (RuntimeError, ValueError):
        raise ValueError(f"device={device!r}: choose auto, cpu or cuda (cuda:N for a given GPU)") from None
    if dev.type not in ("cpu", "cuda"):
        raise ValueError(f"device={device!r}: choose auto, cpu or cuda (cuda:N for a given GPU)")
    if dev.type == "cuda":
        if _STAND_IN is not None:
            return _STAND_IN
        if not torch.cuda.is_available():
            raise ValueError(
                f"device={device!r} but PyTorch sees no CUDA GPU (torch {torch.__version__}); "
                "use device=cpu or device=auto"
            )
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ValueError(f"device={device!r} but only {torch.cuda.device_count()} CUDA GPU(s) are visible")
    return dev


def module_device(module) -> torch.device:
    """Where a module's parameters are (the CPU for a module without any)."""
    p = next(iter(module.parameters()), None)
    return p.device if p is not None else torch.device("cpu")
