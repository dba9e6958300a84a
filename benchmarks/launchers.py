"""Wall time of the same small Taxi sweep on the local launcher and on a local Ray
cluster, side by side in one run (the runs, seeds and settings are identical).

    python benchmarks/launchers.py                 # groups=[ranks], 4 seeds, 20k frames
    python benchmarks/launchers.py --workers 1 2
    python benchmarks/launchers.py --seeds 1 --frames 32 --workers 1 --eval-episodes 1   # a smoke run
"""

from __future__ import annotations

import argparse
import importlib.util
import tempfile
import time

from torchrl_hybrid.experiments.taxi_sweep import SweepConfig, configurations, run_sweep
from torchrl_hybrid.utils.config import merge_dicts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--groups", nargs="+", default=["ranks"])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--frames", type=int, default=20_000)
    ap.add_argument("--workers", type=int, nargs="+", default=[2])
    ap.add_argument("--eval-episodes", type=int, default=16, help="greedy episodes of each evaluation")
    args = ap.parse_args()
    base = {
        "logger": {
            "log_every_frames": 4000,
            "eval_episodes": args.eval_episodes,
            "final_eval_episodes": args.eval_episodes,
        }
    }
    # refuse what would fail only inside the sweep
    if args.seeds < 1:
        ap.error(f"--seeds must be >= 1, got {args.seeds}")
    if any(w < 1 for w in args.workers):
        ap.error(f"--workers must each be >= 1, got {args.workers}")
    if importlib.util.find_spec("ray") is None:
        ap.error("the ray launcher needs Ray: pip install 'ray>=2.9' (or the project's [ray] extra)")
    from torchrl_hybrid.families.gym import config_from_dict

    try:
        for over in configurations(args.groups).values():
            config_from_dict(
                merge_dicts(merge_dicts({"total_frames": args.frames, **base}, over), {"out_dir": "unused"})
            ).validate()
    except ValueError as err:
        ap.error(str(err))
    rows = []
    for workers in args.workers:
        for launcher in ("local", "ray"):
            with tempfile.TemporaryDirectory() as out:
                cfg = SweepConfig(
                    groups=tuple(args.groups),
                    seeds=args.seeds,
                    total_frames=args.frames,
                    out_dir=out,
                    workers=workers,
                    launcher=launcher,
                    base=base,
                )
                t0 = time.perf_counter()
                run_sweep(cfg, show_progress=False)
                rows.append((launcher, workers, time.perf_counter() - t0))
            print(f"{launcher:5s} workers {workers}: {rows[-1][2]:.1f} s", flush=True)
    print("\nlauncher  workers  wall time  vs local")
    for launcher, workers, secs in rows:
        local = next(s for name, w, s in rows if name == "local" and w == workers)
        print(f"{launcher:8s}  {workers:7d}  {secs:8.1f} s  {secs / local:6.2f}x")


if __name__ == "__main__":
    main()
