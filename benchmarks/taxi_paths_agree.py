"""Do the two Taxi training paths learn alike? Trains the same seeds with the
TorchRL collector/trainer path (``train_taxi``) and the batched fast path
(``train_taxi_batched``) and compares their learning curves.

    python benchmarks/taxi_paths_agree.py --seeds 16 --frames 80000 --variant hybrid_dual

Prints per path the mean ± std over seeds of the area under the greedy-return
curve (mean over logged points), the final greedy return and the frames to 95 %
of the optimum, with a permutation-test p-value for the difference of means.
"""
from __future__ import annotations

import argparse
import json
import logging
import tempfile
import time

import numpy as np

from torchrl_hybrid.utils.stats import permutation_p

logging.getLogger("torchrl").setLevel(logging.WARNING)


def compare(variant: str, seeds: int, frames: int, workers_note: str = "") -> dict:
    from torchrl_hybrid.experiments.taxi_sweep import OPTIMAL, frames_to_reach
    from torchrl_hybrid.trainers.batched import train_taxi_batched
    from torchrl_hybrid.trainers.taxi import config_from_dict, train_taxi

    root = tempfile.mkdtemp(prefix="paths_agree_")  # the runs' files are scratch

    def cfg(seed):
        return config_from_dict({"variant": variant, "seed": seed, "total_frames": frames, "device": "cpu",
                                 "out_dir": f"{root}/{variant}_{seed}",
                                 "logger": {"progress_bar": False, "backend": "none", "checkpoint": False}})

    def stats(curves, finals):
        frames_ = np.array([r["frames"] for r in curves[0]])
        ev = np.array([[r["eval_return"] for r in c] for c in curves])
        reach = [frames_to_reach(frames_, c, 0.95 * OPTIMAL) for c in ev]
        return {"auc": ev.mean(1), "final": np.array(finals), "reach": np.array(reach)}

    import csv

    t0 = time.perf_counter()
    torchrl_curves, torchrl_final = [], []
    for s in range(seeds):
        c = cfg(s)
        out = train_taxi(c)
        torchrl_final.append(out["final_return"])
        rows = list(csv.DictReader(open(f"{c.out_dir}/metrics.csv")))
        torchrl_curves.append([{"frames": int(r["frames"]), "eval_return": float(r["eval_return"])} for r in rows])
    t_torchrl = time.perf_counter() - t0
    t0 = time.perf_counter()
    batched = train_taxi_batched([cfg(s) for s in range(seeds)], write_outputs=False)
    t_batched = time.perf_counter() - t0
    A = stats(torchrl_curves, torchrl_final)
    B = stats([b["curve"] for b in batched], [b["final_return"] for b in batched])
    result = {"variant": variant, "seeds": seeds, "frames": frames,
              "time_torchrl_s": round(t_torchrl, 1), "time_batched_s": round(t_batched, 1)}
    for k in ("auc", "final"):
        result[k] = {"torchrl": [float(A[k].mean()), float(A[k].std())],
                     "batched": [float(B[k].mean()), float(B[k].std())],
                     "p_value": permutation_p(A[k], B[k])}
    result["reached_95pct"] = {"torchrl": int((~np.isnan(A["reach"])).sum()),
                               "batched": int((~np.isnan(B["reach"])).sum())}
    return result


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--variant", default="hybrid_dual")
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--frames", type=int, default=80_000)
    p.add_argument("--json", help="also write the result here")
    a = p.parse_args()
    r = compare(a.variant, a.seeds, a.frames)
    print(f"{r['variant']}, {r['seeds']} seeds x {r['frames']:,} frames "
          f"(TorchRL path {r['time_torchrl_s']} s, batched {r['time_batched_s']} s)")
    for k in ("auc", "final"):
        t, b = r[k]["torchrl"], r[k]["batched"]
        print(f"  {k:5s}  TorchRL {t[0]:7.2f} ± {t[1]:5.2f}   batched {b[0]:7.2f} ± {b[1]:5.2f}   "
              f"permutation p = {r[k]['p_value']:.3f}")
    print(f"  seeds reaching 95 % of optimal: TorchRL {r['reached_95pct']['torchrl']}, "
          f"batched {r['reached_95pct']['batched']}")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(r, f, indent=2)


if __name__ == "__main__":
    main()
