"""Do the committed studies still come out of today's code? Each slice reruns the start of one
committed run (a few thousand frames) and compares it with the study's own files.

On the machine that verified them (``results/reproduce.json``: CPU model and torch version) the
slices it found exact are compared exactly: every logged number of the slice's rows, the wall time
aside. Elsewhere, and for the studies that were made on another CPU (the record lists them apart:
their floats differ from the first update on, in the 7th digit, as another CPU's kernels round
differently), only the first logged row's losses are compared, within ``REL_TOL``; later rows move
within the seeds' spread. A code change that moves the numbers fails the comparison; then the
studies are rerun and committed in the same change, and ``python -m
torchrl_hybrid.experiments.reproduce --write`` records the machine and which slices are exact on it.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from torchrl_hybrid.utils.config import merge_dicts
from torchrl_hybrid.utils.files import read_json
from torchrl_hybrid.utils.provenance import provenance

__all__ = ["REL_TOL", "SLICES", "Slice", "exact_here", "run_slice", "same_machine", "slice_name"]

ROOT = Path(__file__).resolve().parents[2]
RECORD = ROOT / "results" / "reproduce.json"
REL_TOL = 1e-3  # another machine: the first logged row's losses (after one update) within this
UNTIMED = ("time_s", "frames_per_s")  # wall-clock columns: never compared


@dataclass(frozen=True)
class Slice:
    """The start of one committed run: ``study`` (a folder under results/), ``run`` (a compare
    run's folder, or a sweep configuration's name) and the frames to rerun."""

    study: str
    run: str
    frames: int
    kind: str  # "gym_run": a compare run (its config.json, metrics.csv); "sweep": a batched sweep configuration


SLICES = (
    # the paper's Taxi study: one configuration, all 16 seeds (the batched engine's numbers depend on how
    # many seeds share the batch), its first two logged points
    Slice("results/taxi", "hybrid_dual", 2100, "sweep"),
    Slice("results/frozenlake_8x8", "hybrid_dual", 2100, "sweep"),
    # the gymnasium comparisons on the TorchRL path: A2C (CartPole) and PPO (MountainCar)
    Slice("results/cartpole/compare", "hybrid_dual_s0", 5_200, "gym_run"),
    Slice("results/mountaincar/compare", "hybrid_dual_ppo_s0", 5_200, "gym_run"),
)


def slice_name(s: Slice) -> str:
    return f"{s.study}/{s.run}"


def exact_here(s: Slice, record: dict[str, Any] | None = None) -> bool:
    """Whether ``s`` is compared exactly on this machine: the recorded machine's kind, and a slice
    that was exact on it."""
    record = read_json(RECORD, "reproduction record") if record is None else record
    return same_machine(record) and slice_name(s) in record["exact"]


def same_machine(record: dict[str, Any] | None = None) -> bool:
    """Whether this machine is the kind that verified the committed studies: CPU (model,
    family/model/stepping, vector extensions) and torch version as recorded in
    ``results/reproduce.json``."""
    record = read_json(RECORD, "reproduction record") if record is None else record
    here, there = provenance()["machine"], record["machine"]
    return all(here.get(k) == there.get(k) for k in ("cpu", "cpu_id", "simd", "torch"))


def _rows_gym_run(s: Slice, out: Path) -> tuple[list[dict], list[dict]]:
    from torchrl_hybrid.families.gym import config_from_dict, train_gym

    run = ROOT / s.study / s.run
    d = read_json(run / "config.json", "run config")
    d = merge_dicts(
        d,
        {
            "total_frames": s.frames,
            "out_dir": str(out),
            "overwrite": True,
            # the final evaluation comes after the last logged row: one episode is enough
            "logger": {"progress_bar": False, "final_eval_episodes": 1},
        },
    )
    if d.get("demo", {}).get("expert"):  # relative to the repository root, as the study ran
        expert = d["demo"]["expert"]
        d["demo"]["expert"] = expert if ":" in expert or Path(expert).is_absolute() else str(ROOT / expert)
    train_gym(config_from_dict(d))
    new = list(csv.DictReader((out / "metrics.csv").open()))[:-1]  # the last row: the slice's own end
    old = list(csv.DictReader((run / "metrics.csv").open()))[: len(new)]
    return new, old


def _rows_sweep(s: Slice, out: Path) -> tuple[list[dict], list[dict]]:
    from torchrl_hybrid.experiments.taxi_sweep import _run_batch, configurations

    saved = read_json(ROOT / s.study / "runs.json", "sweep runs")
    meta, runs = saved["meta"], saved["runs"][s.run]
    over = configurations(meta["groups"])[s.run]
    base = merge_dicts({"total_frames": s.frames, "logger": {"progress_bar": False}}, meta.get("base") or {})
    dicts = [
        merge_dicts(merge_dicts(base, over), {"seed": i, "out_dir": str(out / f"seed_{i}")}) for i in range(len(runs))
    ]
    _, summaries = _run_batch((s.run, dicts, None))
    new, old = [], []
    for mine, theirs in zip(summaries, runs):
        rows = mine["curve"][:-1]
        new += [{"seed": mine["seed"], **r} for r in rows]
        old += [{"seed": theirs["seed"], **r} for r in theirs["curve"][: len(rows)]]
    return new, old


def _number(x: Any) -> float | None:
    try:
        return float(x)
    except (TypeError, ValueError):
        return None


def _equal(a: Any, b: Any) -> bool:
    fa, fb = _number(a), _number(b)
    if fa is not None and fb is not None:
        return fa == fb or (math.isnan(fa) and math.isnan(fb))
    return str(a) == str(b)


def run_slice(s: Slice, exact: bool) -> list[str]:
    """Reruns ``s`` and returns its differences from the committed study (empty: it
    reproduces). ``exact``: every logged number of every row; else the first row's losses
    within :data:`REL_TOL`."""
    with tempfile.TemporaryDirectory() as tmp:
        new, old = (_rows_gym_run if s.kind == "gym_run" else _rows_sweep)(s, Path(tmp) / "run")
    if not new or len(new) != len(old):
        return [f"{s.study}/{s.run}: {len(new)} rows rerun against {len(old)} committed"]
    diffs = []
    for i, (a, b) in enumerate(zip(new, old)):
        if not exact and (i > 0 or s.kind == "sweep"):
            break
        keys = [k for k in a if k not in UNTIMED and (exact or k.startswith("loss_"))]
        for k in keys:
            # older studies name the inverse model's accuracy on the expert's pairs idm_accuracy
            theirs = b.get(k, b.get("idm_accuracy")) if k == "idm_accuracy_expert" else b.get(k)
            if exact and not _equal(a[k], theirs):
                diffs.append(f"{s.study}/{s.run} row {i} ({k}): {a[k]} now, {theirs} committed")
            elif not exact:
                fa, fb = _number(a[k]), _number(theirs)
                if fa is None or fb is None or not math.isclose(fa, fb, rel_tol=REL_TOL, abs_tol=1e-6):
                    diffs.append(f"{s.study}/{s.run} row {i} ({k}): {a[k]} now, {theirs} committed")
    return diffs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--write", action="store_true", help="record this machine and the slices exact on it")
    args = parser.parse_args()
    from torchrl_hybrid.utils.process import configure_process

    configure_process(threads=1)
    exact, failed = [], []
    for s in SLICES:
        if not run_slice(s, exact=True):
            exact.append(slice_name(s))
            print(f"{slice_name(s)} ({s.frames:,} frames): exact")
            continue
        diffs = run_slice(s, exact=False)
        print(f"{slice_name(s)} ({s.frames:,} frames): " + ("within tolerance" if not diffs else "DIFFERENT"))
        failed += diffs
    if failed:
        raise SystemExit("\n".join(failed[:20]))
    if args.write:
        p = provenance()
        record = {"verified": p["date"], "commit": p["commit"], "machine": p["machine"], "exact": exact}
        RECORD.write_text(json.dumps(record, indent=2) + "\n")
        print(f"recorded this machine and {len(exact)} exact slice(s) in {RECORD}")


if __name__ == "__main__":
    main()
