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

__all__ = [
    "RUN_FILES",
    "take_lock",
    "check_memmap_folder",
    "check_resume_target",
    "checkpoint_frames",
    "out_dir_problem",
    "out_dir_from_overrides",
    "prepare_out_dir",
    "read_json",
]

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
                raise ValueError(
                    f"{file} holds {size:,} bytes but {meta_path} describes {expected:,} "
                    f"(shape {entry['shape']}, {entry['dtype']}): the file is truncated or damaged"
                )


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
        print(
            f"resume: {ckpt} was being replaced when its run stopped; restored the previous one ({backups[-1].name})",
            flush=True,
        )


def out_dir_problem(out: str | Path) -> str | None:
    """Why ``out`` cannot be a run's folder (it, or a folder above it, is a file), as one
    line naming the setting and the fix; ``None`` when it can."""
    out = Path(out)
    for p in (out, *out.parents):
        if p.exists() and not p.is_dir():
            what = "is a file" if p == out else f"is inside {p}, which is a file"
            return f"out_dir={out} {what}, not a folder; choose another out_dir (or move the file away)"
    return None


def out_dir_from_overrides(overrides: list[str]) -> str | None:
    """The folder a Hydra command line puts its run in (``out_dir=...`` or
    ``hydra.run.dir=...``, the last one given; ``None`` when neither is given or when the
    value is an interpolation only Hydra resolves)."""
    found = None
    for arg in overrides:
        key, eq, value = arg.partition("=")
        if eq and key.lstrip("+~") in ("out_dir", "hydra.run.dir"):
            value = value.strip()
            if len(value) >= 2 and value[0] == value[-1] and value[0] in "'\"":
                value = value[1:-1]
            found = None if "${" in value or not value else value
    return found


def checkpoint_frames(ckpt: str | Path) -> int | None:
    """The frames a TorchRL trainer checkpoint (``out_dir/checkpoint``) had collected, read
    from its ``trainer_state`` component without loading it; ``None`` when the folder is not
    in the format this reads (the frames are then known only once it is loaded)."""
    ckpt = Path(ckpt)
    try:
        manifest = json.loads((ckpt / "manifest.json").read_text())
        state = json.loads((ckpt / manifest["components"]["trainer_state"]["path"] / "state.json").read_text())
        for key, value in state["items"]:
            if key.get("value") == "collected_frames":
                frames = value.get("value")
                return frames if isinstance(frames, int) and not isinstance(frames, bool) else None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        pass
    return None


def check_resume_target(out: str | Path, total_frames: int, checkpoint: str = "checkpoint") -> None:
    """``resume=true`` on a run whose checkpoint already has ``total_frames`` (or more) is
    refused, before any file of the run is touched: resuming it would train nothing and
    rewrite its summary and model with this run's ``total_frames``."""
    out = Path(out)
    ckpt = out / checkpoint
    if not ckpt.is_dir():
        return  # nothing to resume (prepare_out_dir says what is wrong, if anything)
    frames = checkpoint_frames(ckpt)
    if frames is None and (out / "summary.json").is_file():  # another checkpoint format: the finished run's summary
        data = read_json(out / "summary.json", "run summary")
        frames = data.get("frames") if isinstance(data, dict) else None
        frames = frames if isinstance(frames, int) and not isinstance(frames, bool) else None
    if frames is not None and frames >= total_frames:
        raise ValueError(
            f"resume=true: the run in {out} is already at {frames:,} frames; raise total_frames "
            f"(now {total_frames:,}) to train further"
        )


def take_lock(path: Path, holder: str):
    """An exclusive lock on ``path`` (created), held while the returned file stays open; the OS
    releases it when the process ends, even on SIGKILL. Refused in one line while ``holder``
    (e.g. "another run") holds it."""
    lock = open(path, "w")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.close()
        raise ValueError(
            f"out_dir {path.parent} is in use by {holder} (it holds {path}); "
            "wait for it to finish or choose another out_dir"
        ) from None
    return lock


def prepare_out_dir(out: str | Path, *, resume: bool = False, overwrite: bool = False, checkpoint: str = "checkpoint"):
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
    problem = out_dir_problem(out)
    if problem:
        raise ValueError(problem)
    out.mkdir(parents=True, exist_ok=True)
    lock = take_lock(out / ".lock", "another run")
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
            raise ValueError(
                f"resume=true but {out} has no {checkpoint}/ to resume from, only {present}; "
                "pass overwrite=true to start again there, or choose another out_dir"
            )
        elif not resume and any(f != "logs" for f in present):
            state = "finished" if "summary.json" in present else "started"
            raise ValueError(
                f"out_dir {out} holds a {state} run ({', '.join(present)}); pass overwrite=true to "
                "replace it, resume=true to continue it, or choose another out_dir"
            )
    except Exception:
        lock.close()
        raise
    return lock
