"""Process-wide settings, made by whoever owns the process (a recipe, a study's worker
process), never by the library functions a user calls from their own code."""

from __future__ import annotations

import logging
import os
import sys
import warnings

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
    :func:`~torchrl_hybrid.utils.launch.run_jobs`; nothing in the caller's own process,
    but a warning when its torch thread count is not the ``threads`` the job asks for
    (``run_jobs(..., workers=1)`` runs jobs there: set it with :func:`configure_process`
    or ``torch.set_num_threads`` first)."""
    from torchrl_hybrid.utils.launch import in_worker

    if in_worker():
        configure_process(threads)
    elif threads and torch.get_num_threads() != int(threads):
        warnings.warn(
            f"this job asks for {int(threads)} torch thread(s) but runs in the calling process, which "
            f"has {torch.get_num_threads()} (workers=1 leaves the caller's settings alone): call "
            f"torchrl_hybrid.utils.process.configure_process({int(threads)}) first, or more runs "
            "side by side than cores will crawl",
            RuntimeWarning,
            stacklevel=2,
        )
