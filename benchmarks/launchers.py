"""Wall time of the same small Taxi sweep on the local launcher and on a local Ray
cluster, side by side in one run (the runs, seeds and settings are identical).

    python benchmarks/launchers.py                 # groups=[ranks], 4 seeds, 20k frames
    python benchmarks/launchers.py --workers 1 2
"""
from __future__ import annotations

import argparse
import tempfile
import time

from torchrl_hybrid.experiments.taxi_sweep import SweepConfig, run_sweep


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--groups", nargs="+", default=["ranks"])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--frames", type=int, default=20_000)
    ap.add_argument("--workers", type=int, nargs="+", default=[2])
    args = ap.parse_args()
    base = {"logger": {"log_every_frames": 4000, "eval_episodes": 16, "final_eval_episodes": 16}}
    rows = []
    for workers in args.workers:
        for launcher in ("local", "ray"):
            with tempfile.TemporaryDirectory() as out:
                cfg = SweepConfig(groups=tuple(args.groups), seeds=args.seeds, total_frames=args.frames,
                                  out_dir=out, workers=workers, launcher=launcher, base=base)
                t0 = time.perf_counter()
                run_sweep(cfg, show_progress=False)
                rows.append((launcher, workers, time.perf_counter() - t0))
            print(f"{launcher:5s} workers {workers}: {rows[-1][2]:.1f} s", flush=True)
    print("\nlauncher  workers  wall time  vs local")
    for launcher, workers, secs in rows:
        local = next(s for l, w, s in rows if l == "local" and w == workers)
        print(f"{launcher:8s}  {workers:7d}  {secs:8.1f} s  {secs / local:6.2f}x")


if __name__ == "__main__":
    main()
