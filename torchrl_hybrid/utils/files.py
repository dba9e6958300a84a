"""Safe outputs and inputs: run folders that are never silently overwritten or shared,
memory-mapped folders checked against their metadata before they are opened."""
from __future__ import annotations

import fcntl
import json
import math
import shutil
from pathlib import Path
from typing import Any

import torch

__all__ = ["RUN_FILES", "check_memmap_folder", "prepare_out_dir", "read_json"]

#: what a training run writes into its out_dir (``overwrite=true`` removes exactly these)
RUN_FILES = ("summary.json", "model.pt", "metrics.csv", "learning_curve.png", "config.json", "checkpoint", "logs")


def read_json(path: str | Path, what: str = "file") -> Any:
    """``json.loads`` of a file, with an error that names the file."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"{path}: malformed {what} ({err}); restore or delete it") from None
    except IsADirectoryError:
        raise ValueError(f"{path}: expected a JSON {what}, found a folder") from None


def _itemsize(dtype: str) -> int:
    name = dtype.removeprefix("torch.")
    if not hasattr(torch, name) or not isinstance(getattr(torch, name), torch.dtype):
        raise ValueError(f"unknown dtype {dtype!r}")
    return torch.empty(0, dtype=getattr(torch, name)).element_size()


def check_memmap_folder(path: str | Path) -> None:
    """Checks a folder written by ``TensorDict.memmap`` before it is loaded: every
    ``meta.json`` parses and every tensor file holds exactly the bytes its shape and
    dtype need. A truncated file would otherwise be padded with zeros on load (and
    the file extended on disk). Raises ``ValueError`` naming the file."""
    root = Path(path)
    metas = sorted(root.rglob("meta.json"))
    if not metas:
        raise ValueError(f"{root}: no meta.json; not a folder written by TensorDict.memmap")
    for meta_path in metas:
        meta = read_json(meta_path, "TensorDict metadata")
        if not isinstance(meta, dict):
            raise ValueError(f"{meta_path}: malformed TensorDict metadata (not a JSON object)")
        for key, entry in meta.items():
            if not isinstance(entry, dict) or "shape" not in entry or "dtype" not in entry:
                continue  # a nested TensorDict or the folder's own shape/device entries
            file = meta_path.parent / f"{key}.memmap"
            try:
                expected = math.prod(entry["shape"]) * _itemsize(entry["dtype"])
            except (TypeError, ValueError) as err:
                raise ValueError(f"{meta_path}: malformed entry for {key!r} ({err})") from None
            if not file.exists():
                raise ValueError(f"{file} is missing (listed in {meta_path})")
            size = file.stat().st_size
            if size != expected:
                raise ValueError(f"{file} holds {size:,} bytes but {meta_path} describes {expected:,} "
                                 f"(shape {entry['shape']}, {entry['dtype']}): the file is truncated or damaged")


def _recover_checkpoint(ckpt: Path) -> None:
    """TorchRL's ``Checkpoint`` writes into ``.<name>.stage-*``, moves the old checkpoint
    to ``.<name>.backup-*``, then the stage into place. A process killed between those
    two renames leaves no checkpoint but the complete old one as a backup: put it back.
    An unfinished stage (killed while writing) is left alone; the old checkpoint stands."""
    if ckpt.exists():
        return
    backups = sorted(ckpt.parent.glob(f".{ckpt.name}.backup-*"), key=lambda p: p.stat().st_mtime)
    if backups:
        backups[-1].rename(ckpt)
        print(f"resume: {ckpt} was being replaced when its run stopped; restored the previous one "
              f"({backups[-1].name})", flush=True)


def prepare_out_dir(out: str | Path, *, resume: bool = False, overwrite: bool = False,
                    checkpoint: str = "checkpoint"):
    """Makes ``out`` ready for a run and returns the open lock file (keep it for the
    run's lifetime; the OS releases it when the process ends, even on SIGKILL).

    - A second run on the same folder is refused while the first holds the lock.
    - A folder holding a run's results is refused unless ``resume`` (continue from
      its checkpoint) or ``overwrite`` (remove the run's own files, :data:`RUN_FILES`;
      nothing else in the folder is touched).
    - ``resume`` over results without a checkpoint is refused: it would start from
      scratch over them.
    """
    out = Path(out)
    if resume and overwrite:
        raise ValueError("resume=true and overwrite=true contradict each other: choose one")
    if out.exists() and not out.is_dir():
        raise ValueError(f"out_dir {out} is a file, not a folder")
    out.mkdir(parents=True, exist_ok=True)
    lock = open(out / ".lock", "w")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.close()
        raise ValueError(f"out_dir {out} is in use by another run (it holds {out / '.lock'}); "
                         "wait for that run or choose another out_dir") from None
    if resume:
        _recover_checkpoint(out / checkpoint)
    present = [f for f in RUN_FILES if (out / f).exists()]
    has_ckpt = (out / checkpoint).exists()
    try:
        if overwrite:
            for f in present:
                p = out / f
                shutil.rmtree(p) if p.is_dir() else p.unlink()
        elif resume and not has_ckpt and any(f != "logs" for f in present):
            raise ValueError(f"resume=true but {out} has no {checkpoint}/ to resume from, only {present}; "
                             "pass overwrite=true to start again there, or choose another out_dir")
        elif not resume and any(f != "logs" for f in present):
            state = "finished" if "summary.json" in present else "started"
            raise ValueError(f"out_dir {out} holds a {state} run ({', '.join(present)}); pass overwrite=true to "
                             "replace it, resume=true to continue it, or choose another out_dir")
    except Exception:
        lock.close()
        raise
    return lock

