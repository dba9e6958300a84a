"""Do the two Taxi training paths learn alike? Trains the same seeds with the
TorchRL collector/trainer path (``train_gym``) and the batched fast path
(``train_taxi_batched``) and compares their learning curves.

    python benchmarks/taxi_paths_agree.py --seeds 16 --frames 80000 --variant hybrid_dual
    python benchmarks/taxi_paths_agree.py --seeds 2 --frames 32 --eval-episodes 1   # a smoke run

Prints per path the mean ± std over seeds of the area under the greedy-return
curve (mean over logged points), the final greedy return and the frames to 95 %
of the optimum, with a permutation-test p-value for the difference of means.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import tempfile
import time

import numpy as np

from torchrl_hybrid.utils.stats import permutation_p

logging.getLogger("torchrl").setLevel(logging.WARNING)


def run_config(variant: str, seed: int, frames: int, out_dir: str, logger: dict | None = None):
    """One seed's run (both paths train from the same settings)."""
    from torchrl_hybrid.families.gym import config_from_dict

    return config_from_dict(
        {
            "variant": variant,
            "seed": seed,
            "total_frames": frames,
            "device": "cpu",
            "out_dir": out_dir,
            "logger": {"progress_bar": False, "backend": "none", "checkpoint": False, **(logger or {})},
        }
    )


def compare(variant: str, seeds: int, frames: int, workers_note: str = "", logger: dict | None = None) -> dict:
    """``logger``: overrides of the runs' logger settings (e.g. fewer evaluation episodes)."""
    if seeds < 2:
        raise ValueError(f"seeds={seeds}: the permutation test compares the paths over seeds, it needs >= 2")
    with tempfile.TemporaryDirectory(prefix="paths_agree_") as root:  # the runs' files are scratch
        return _compare(variant, seeds, frames, root, logger)


def _compare(variant: str, seeds: int, frames: int, root: str, logger: dict | None) -> dict:
    from torchrl_hybrid.experiments.taxi_sweep import OPTIMAL, frames_to_reach
    from torchrl_hybrid.families.gym import train_gym
    from torchrl_hybrid.families.gym_batched import train_taxi_batched

    def cfg(seed):
        return run_config(variant, seed, frames, f"{root}/{variant}_{seed}", logger)

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
        out = train_gym(c)
        torchrl_final.append(out["final_return"])
        with open(f"{c.out_dir}/metrics.csv") as f:
            rows = list(csv.DictReader(f))
        torchrl_curves.append([{"frames": int(r["frames"]), "eval_return": float(r["eval_return"])} for r in rows])
    t_torchrl = time.perf_counter() - t0
    t0 = time.perf_counter()
    batched = train_taxi_batched([cfg(s) for s in range(seeds)], write_outputs=False)
    t_batched = time.perf_counter() - t0
    A = stats(torchrl_curves, torchrl_final)
    B = stats([b["curve"] for b in batched], [b["final_return"] for b in batched])
    result = {
        "variant": variant,
        "seeds": seeds,
        "frames": frames,
        "time_torchrl_s": round(t_torchrl, 1),
        "time_batched_s": round(t_batched, 1),
    }
    for k in ("auc", "final"):
        result[k] = {
            "torchrl": [float(A[k].mean()), float(A[k].std())],
            "batched": [float(B[k].mean()), float(B[k].std())],
            "p_value": permutation_p(A[k], B[k]),
        }
    result["reached_95pct"] = {
        "torchrl": int((~np.isnan(A["reach"])).sum()),
        "batched": int((~np.isnan(B["reach"])).sum()),
    }
    return result


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--variant", default="hybrid_dual")
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--frames", type=int, default=80_000)
    p.add_argument(
        "--eval-episodes",
        type=int,
        default=None,
        help="greedy episodes of each evaluation (default: the runs' own, logger.eval_episodes and "
        "logger.final_eval_episodes)",
    )
    p.add_argument("--json", help="also write the result here")
    a = p.parse_args()
    # refuse what would fail only after the training
    if a.seeds < 2:
        p.error(f"--seeds {a.seeds}: the permutation test compares the two paths over seeds, it needs >= 2")
    logger = (
        None if a.eval_episodes is None else {"eval_episodes": a.eval_episodes, "final_eval_episodes": a.eval_episodes}
    )
    try:
        run_config(a.variant, 0, a.frames, "unused", logger).validate()
    except ValueError as err:
        p.error(str(err))
    if a.json and not os.path.isdir(os.path.dirname(os.path.abspath(a.json))):
        p.error(f"--json {a.json}: its folder does not exist")
    r = compare(a.variant, a.seeds, a.frames, logger=logger)
    print(
        f"{r['variant']}, {r['seeds']} seeds x {r['frames']:,} frames "
        f"(TorchRL path {r['time_torchrl_s']} s, batched {r['time_batched_s']} s)"
    )
    for k in ("auc", "final"):
        t, b = r[k]["torchrl"], r[k]["batched"]
        print(
            f"  {k:5s}  TorchRL {t[0]:7.2f} ± {t[1]:5.2f}   batched {b[0]:7.2f} ± {b[1]:5.2f}   "
            f"permutation p = {r[k]['p_value']:.3f}"
        )
    print(
        f"  seeds reaching 95 % of optimal: TorchRL {r['reached_95pct']['torchrl']}, "
        f"batched {r['reached_95pct']['batched']}"
    )
    if a.json:
        with open(a.json, "w") as f:
            json.dump(r, f, indent=2)


if __name__ == "__main__":
    main()
