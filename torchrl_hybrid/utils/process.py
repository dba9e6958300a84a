"""Process-wide settings, made by whoever owns the process (a recipe, a study's worker
process), never by the library functions a user calls from their own code."""
from __future__ import annotations

import logging
import os
import sys

import torch

__all__ = ["configure_process", "configure_worker"]


def configure_process(threads: int | None = None) -> None:
    """Sets torch's thread count (``threads`` > 0; ``None`` or 0 leaves it), TorchRL's log
    level (warnings and above) and tqdm's refresh: once a second on a terminal, every
    30 s when the output goes to a log file (an environment default; an explicit
    ``TQDM_MININTERVAL`` wins)."""
    import torchrl  # noqa: F401  (importing torchrl sets its logger to INFO: import it first)

    logging.getLogger("torchrl").setLevel(logging.WARNING)
    os.environ.setdefault("TQDM_MININTERVAL", "1" if sys.stderr.isatty() else "30")
    if threads:
        torch.set_num_threads(int(threads))


def configure_worker(threads: int | None = None) -> None:
    """:func:`configure_process` in a worker process started by
    :func:`~torchrl_hybrid.utils.launch.run_jobs`; nothing in the caller's own process."""
    from torchrl_hybrid.utils.launch import in_worker

    if in_worker():
        configure_process(threads)
