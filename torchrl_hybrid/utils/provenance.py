"""Where a result was made: the commit, the command and the machine.

Seeded runs repeat exactly on the machine that made them; on another CPU the floats differ from the
first update on, and the numbers move within the seeds' spread. Each study records this, so that its
README can say where its numbers hold."""

from __future__ import annotations

import datetime
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

__all__ = ["provenance", "provenance_line"]

_ROOT = Path(__file__).resolve().parents[2]


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=_ROOT, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def _cpuinfo() -> dict[str, str]:
    """The first processor's fields of /proc/cpuinfo ({} where there is none)."""
    info: dict[str, str] = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if not line.strip():
                break
            key, _, value = line.partition(":")
            info[key.strip()] = value.strip()
    except OSError:
        pass
    return info


def _cpu() -> dict[str, str]:
    """The CPU's model name, its family/model/stepping (a virtual machine's model name can be as
    vague as "AMD EPYC") and its vector extensions: what decides how its float kernels round."""
    info = _cpuinfo()
    simd = sorted(f for f in info.get("flags", "").split() if f.startswith(("avx", "sse4", "fma", "amx")))
    return {
        "cpu": info.get("model name") or platform.processor() or platform.machine(),
        "cpu_id": " ".join(f"{k} {info[k]}" for k in ("cpu family", "model", "stepping") if k in info),
        "simd": " ".join(simd),
    }


def provenance() -> dict[str, Any]:
    """The commit (and whether the working tree had uncommitted changes), the command, the
    date, and the machine: CPU (model, family/model/stepping, vector extensions), core count,
    GPU, torch version and threads, Python, OS."""
    import torch

    commit = _git("rev-parse", "HEAD")
    status = _git("status", "--porcelain", "--untracked-files=no") if commit else None
    return {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "commit": commit,
        "uncommitted_changes": bool(status) if status is not None else None,
        "command": shlex.join([Path(sys.executable).name, *sys.argv]),
        "machine": {
            **_cpu(),
            "cores": os.cpu_count(),
            "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
            "torch": torch.__version__,
            "torch_threads": torch.get_num_threads(),
            "python": platform.python_version(),
            "os": platform.platform(terse=True),
        },
    }


def provenance_line(record: dict[str, Any]) -> str:
    """One Markdown line saying where a study's numbers were made and where they hold."""
    m = record.get("machine", {})
    commit = (record.get("commit") or "unknown commit")[:10] + (
        " + changes" if record.get("uncommitted_changes") else ""
    )
    gpu = f", {m['gpu']}" if m.get("gpu") else ""
    return (
        f"Made at commit {commit} on {m.get('cpu', '?')} ({m.get('cpu_id') or 'CPU id unknown'}, {m.get('cores', '?')} cores{gpu}, torch {m.get('torch', '?')}, "
        f"{m.get('torch_threads', '?')} threads), {record.get('date', '?')[:10]}. Seeded runs repeat exactly on that "
        "machine; on another CPU the floats differ from the first update on and the numbers move within the seeds' "
        "spread."
    )
