"""A study (a comparison or a sweep: many runs and their analysis in one folder) as a unit,
as a run is one (:func:`torchrl_hybrid.utils.files.prepare_out_dir`):

- :func:`open_study` takes the folder: one study at a time (a lock the OS releases when the
  process ends, even on SIGKILL), a folder that holds something else is refused, and
  ``study.json`` says which kind of study the folder holds.
- :func:`changed_runs` finds the finished runs of the folder that were made with other
  settings than the ones asked for now. A study refuses to report them as the runs asked
  for: it names each difference, and ``overwrite=true`` runs them again with the new ones.

``gym_compare``, ``atari_compare`` and ``taxi_sweep`` all go through these.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from torchrl_hybrid.utils.config import flatten_dict
from torchrl_hybrid.utils.files import read_json, take_lock
from torchrl_hybrid.utils.provenance import provenance, provenance_line

__all__ = [
    "STUDY_FILE",
    "Study",
    "open_study",
    "settings_diff",
    "changed_runs",
    "refuse_changed",
    "planned_run",
    "runs_to_do",
]

#: what a study writes at the top of its folder: its kind (and nothing a run needs)
STUDY_FILE = "study.json"
_LOCK = ".study.lock"


class Study:
    """An open study folder (from :func:`open_study`): holds the lock until :meth:`close`
    (or the end of a ``with`` block, or of the process)."""

    def __init__(self, out: Path, kind: str, lock):
        self.out, self.kind, self._lock = out, kind, lock

    def record_session(self) -> None:
        """Appends where this session trains (commit, command, machine: utils/provenance.py) to
        ``study.json``; called once the plan has passed its checks and runs are about to train."""
        record = self.out / STUDY_FILE
        saved = read_json(record, "study record")
        saved.setdefault("sessions", []).append(provenance())
        _write_record(record, saved)

    def close(self) -> None:
        if self._lock is not None:
            self._lock.close()
            self._lock = None

    def __enter__(self) -> Study:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_study(out_dir: str | Path, kind: str, *, looks_like: Callable[[Path], bool], overwrite: bool = False) -> Study:
    """Takes ``out_dir`` for a study of ``kind`` (e.g. ``"gym_compare"``).

    - a file there, or a study of another kind (its ``study.json``), is refused;
    - a folder with files but no ``study.json`` is taken only when ``looks_like(folder)``
      says it holds this kind of study (one written before ``study.json`` existed) or with
      ``overwrite`` (the study then writes its own files there and touches nothing else);
    - a second study on the same folder is refused while the first runs.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out_dir {out} is a file, not a folder; choose another out_dir")
    record = out / STUDY_FILE
    if record.exists():
        saved = read_json(record, "study record")
        found = saved.get("kind") if isinstance(saved, dict) else None
        if found != kind:
            raise ValueError(
                f"out_dir {out} holds a {found!r} study ({record}), not a {kind!r} one; choose another out_dir"
            )
    elif out.exists() and any(p.name != _LOCK for p in out.iterdir()) and not looks_like(out) and not overwrite:
        shown = sorted(p.name for p in out.iterdir())[:5]
        raise ValueError(
            f"out_dir {out} holds files that are not a {kind} study ({', '.join(shown)}, ...); "
            "choose an empty or new out_dir, or pass overwrite=true to write the study's files "
            "there beside them"
        )
    out.mkdir(parents=True, exist_ok=True)
    lock = take_lock(out / _LOCK, "another study")
    if not record.exists():
        _write_record(record, {"kind": kind})
    return Study(out, kind, lock)


def _write_record(record: Path, data: dict) -> None:
    tmp = record.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=2))
    tmp.replace(record)


def study_provenance(out_dir: str | Path) -> str | None:
    """The README line saying where the study's last session ran (None for a study written
    before ``study.json`` recorded it)."""
    record = Path(out_dir) / STUDY_FILE
    sessions = read_json(record, "study record").get("sessions") if record.exists() else None
    return provenance_line(sessions[-1]) if sessions else None


def settings_diff(
    saved: dict, now: dict, keys: Iterable[str], *, ignore: Iterable[str] = (), defaults: dict | None = None
) -> list[str]:
    """The settings under ``keys`` (top-level names, or dotted names of single settings)
    on which two full run configs differ, as ``"name: saved -> now"``. A setting ``saved``
    lacks (the project added it after that run) counts as its value in ``defaults``."""
    keys, ignore = tuple(keys), set(ignore)

    def pick(d: dict) -> dict[str, Any]:
        flat = flatten_dict(d)
        return {k: v for k, v in flat.items() if any(k == p or k.startswith(p + ".") for p in keys) and k not in ignore}

    old, new = pick(saved), pick(now)
    for k, v in pick(defaults or {}).items():
        old.setdefault(k, v)
    return [f"{k}: {old.get(k)!r} -> {new.get(k)!r}" for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k)]


def changed_runs(
    runs: Iterable[tuple[str, Path, dict]],
    keys: Iterable[str],
    *,
    ignore: Iterable[str] = (),
    defaults: dict | None = None,
) -> dict[str, list[str]]:
    """``{name: differences}`` for each run of the folder, finished or started (it has a
    ``config.json``), whose settings differ from the full config asked for now: a finished
    one would be reported as the run asked for, a started one resumed. ``runs`` gives
    ``(name, run_dir, config now)``. A finished run without ``config.json`` counts as
    changed (its settings cannot be checked)."""
    keys = tuple(keys)
    out: dict[str, list[str]] = {}
    for name, run_dir, now in runs:
        path = run_dir / "config.json"
        if not path.exists():
            if (run_dir / "summary.json").exists():
                out[name] = [f"no {path.name} (its settings cannot be checked)"]
            continue
        diff = settings_diff(read_json(path, "run config"), now, keys, ignore=ignore, defaults=defaults)
        if diff:
            out[name] = diff
    return out


def refuse_changed(changed: dict[str, list[str]], out_dir: str | Path, overwrite_hint: str = "overwrite=true") -> None:
    """Raises the one error a study gives for finished runs made with other settings."""
    if not changed:
        return
    first = list(changed.items())[:3]
    shown = "; ".join(f"{name}: {', '.join(d[:4])}" + (" ..." if len(d) > 4 else "") for name, d in first)
    more = f" (and {len(changed) - len(first)} more)" if len(changed) > len(first) else ""
    raise ValueError(
        f"{len(changed)} run(s) in {out_dir} were made with other settings than asked now "
        f"({shown}{more}); choose another out_dir, run with the same settings, or pass "
        f"{overwrite_hint} to run them again with the new ones"
    )


def planned_run(name: str, out: Path, d: dict, make_config: Callable[[dict], Any]) -> tuple[str, Path, dict, dict]:
    """``(name, run_dir, job dict, full config as a dict)`` of one run of a study; a misspelt
    or out-of-range setting fails here, before any run has started, naming the run."""
    import dataclasses

    try:
        full = make_config(d)
        full.validate()
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name.rpartition('_s')[0]}: {err}") from None
    return name, out, d, dataclasses.asdict(full)


def runs_to_do(
    planned: list[tuple[str, Path, dict, dict]],
    out_dir: str | Path,
    keys: Iterable[str],
    *,
    ignore: Iterable[str] = (),
    defaults: dict | None = None,
    overwrite: bool = False,
) -> tuple[list[tuple[str, dict]], dict[str, list[str]]]:
    """The runs of ``planned`` (from :func:`planned_run`) to start: those not finished, and
    (with ``overwrite``) those made with other settings, whose job then says ``overwrite``;
    without ``overwrite`` runs of other settings are refused (:func:`refuse_changed`).
    Returns ``([(name, job)], changed)``."""
    changed = changed_runs([(n, out, full) for n, out, _, full in planned], keys, ignore=ignore, defaults=defaults)
    if not overwrite:
        refuse_changed(changed, out_dir)
    jobs = [
        (n, {**d, "overwrite": True} if n in changed else d)
        for n, out, d, _ in planned
        if n in changed or not (out / "summary.json").exists()
    ]
    return jobs, changed
