"""The README's headline table: every env's comparison in one table (RL base, the paper's
hybrid, the best arm with inferred labels, the oracle; the issue's two goals per env).

    python recipes/headline.py                       # the studies committed under results/
    python recipes/headline.py cartpole=results/cartpole/compare   # others: label=out_dir ...

Reads each comparison's summary.json (recipes/compare.py writes it) and rewrites the block
between <!-- headline:start --> and <!-- headline:end --> in README.md and docs/results.md.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from torchrl_hybrid.experiments.headline import headline_markdown, headline_rows, update_readme_block

ROOT = Path(__file__).resolve().parents[1]
STUDIES = {
    "CartPole-v1": "results/cartpole/compare",
    "Acrobot-v1": "results/acrobot/compare",
    "MountainCar-v0": "results/mountaincar/compare",
    "LunarLander-v3": "results/lunarlander/compare",
    "Taxi-v4": "results/taxi_compare",
    "FrozenLake 8x8": "results/frozenlake_8x8/compare",
}


def main(argv: list[str]) -> None:
    os.chdir(ROOT)  # the links in the table are relative to the README
    bad = [a for a in argv if "=" not in a]
    if bad:
        raise ValueError(f"{bad}: give each study as label=out_dir, e.g. cartpole=results/cartpole/compare")
    studies = dict(a.split("=", 1) for a in argv) if argv else STUDIES
    present = {k: v for k, v in studies.items() if (Path(v) / "summary.json").exists()}
    missing = [k for k in studies if k not in present]
    table = headline_markdown(headline_rows(present))
    if missing:
        table += (
            "\n\nNo comparison of this form yet (5 seeds with the oracle arm): "
            + ", ".join(missing)
            + ". Taxi's and FrozenLake's hybrid-vs-A2C results are the sweeps in results/taxi and "
            "results/frozenlake_8x8."
        )
    print(table)
    if not argv:
        for page in ("README.md", "docs/results.md"):  # the README's headline and the docs' results page
            update_readme_block(ROOT / page, table)


if __name__ == "__main__":
    try:
        main(sys.argv[1:])
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
