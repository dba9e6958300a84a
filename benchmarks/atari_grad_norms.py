"""How large each run's gradient was before the clip, per stretch of the run: the logged
``grad_norm`` (the norm of the summed losses' gradient over every parameter, before
``optim.max_grad_norm`` scales it down) of finished comparison runs, averaged over frame windows.

    python benchmarks/atari_grad_norms.py results/atari/compare_5m --games BeamRider Breakout Qbert

In the hybrid agents the inverse model shares the CNN with actor and critic (the paper's
architecture), so its loss and the BC term add to A2C's gradient. Where the sum is far above
the clip (0.5 here) the whole update, A2C's part included, is scaled down to that norm, and
RMSprop's per-parameter normaliser on the shared CNN is set by the larger terms. This prints
the sizes side by side; it does not by itself show that they slow learning (a run with a
smaller ``loss.idm_action_coeff`` or its own inverse-model CNN would).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path

from torchrl_hybrid.experiments.atari_compare import grad_norm_key

WINDOWS = ((0, 100_000), (200_000, 2_000_000), (2_500_000, 5_000_000))


def grad_norms(run_dir: Path, windows=WINDOWS) -> dict:
    """The mean ``grad_norm`` of ``run_dir/metrics.csv`` in each ``(lo, hi]`` frame window
    (NaN where none was logged), with the run's clip (``optim.max_grad_norm``)."""
    with open(run_dir / "metrics.csv") as f:
        table = list(csv.DictReader(f))
    key = grad_norm_key(table[0] if table else {})  # per_group clip: the policy group's norm
    rows = [(float(r["frames"]), float(r[key])) for r in table if r.get(key) not in (None, "")]
    if not rows:
        raise ValueError(f"{run_dir}/metrics.csv logs no grad_norm")
    means = []
    for lo, hi in windows:
        xs = [g for fr, g in rows if lo < fr <= hi]
        means.append(sum(xs) / len(xs) if xs else math.nan)
    cfg = run_dir / "config.json"
    clip = json.loads(cfg.read_text()).get("optim", {}).get("max_grad_norm") if cfg.exists() else None
    return {
        "run": run_dir.name,
        "key": key,
        "windows": [list(w) for w in windows],
        "mean_grad_norm": means,
        "clip": clip,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out_dir", help="a comparison folder (recipes/atari_compare.py out_dir): <game>/<arm>_s<seed>/")
    p.add_argument("--games", nargs="+", required=True)
    p.add_argument("--json", default=None, help="write the result as JSON")
    args = p.parse_args()
    if not Path(args.out_dir).is_dir():
        p.error(f"{args.out_dir}: no such folder")
    if args.json and not Path(args.json).resolve().parent.is_dir():
        p.error(f"--json {args.json}: its folder does not exist")
    runs = {}
    for game in args.games:  # every game has runs before the first one is read
        runs[game] = sorted(d for d in (Path(args.out_dir) / game).glob("*_s*") if (d / "summary.json").exists())
        if not runs[game]:
            p.error(f"no finished run (<arm>_s<seed>/summary.json) in {Path(args.out_dir) / game}")
    result = {}
    head = "  ".join(f"{lo / 1e6:g}-{hi / 1e6:g}M" for lo, hi in WINDOWS)
    for game in args.games:
        print(f"{game}: mean gradient norm before the clip ({head})")
        result[game] = []
        for d in runs[game]:
            r = grad_norms(d)
            result[game].append(r)
            print(
                f"  {d.name:32s} "
                + "  ".join(f"{g:8.3f}" for g in r["mean_grad_norm"])
                + f"   clip {r['clip']}"
                + ("" if r["key"] == "grad_norm" else f" ({r['key']}: per-group clip)")
            )
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
