"""Reproduce the paper's Taxi results: every configuration x 16 seeds, then the
figures, curves, parameter table and claims table in results/taxi/.

    python recipes/taxi_sweep.py out_dir=results/taxi     # the full study, into the committed folder
    python recipes/taxi_sweep.py groups=[agents] seeds=4  # a subset

Options: recipes/config/taxi_sweep.yaml.
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig, OmegaConf

from torchrl_hybrid.experiments.taxi_sweep import SweepConfig, run_sweep
from torchrl_hybrid.utils.process import configure_process


@hydra.main(config_path="config", config_name="taxi_sweep", version_base=None)
def main(cfg: DictConfig) -> None:
    raw = OmegaConf.to_container(cfg, resolve=True)
    raw.pop("hydra", None)
    configure_process(1)
    try:
        sweep = SweepConfig(**raw)
        run_sweep(sweep)
    except (ValueError, TypeError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    print(f"\nresults: {sweep.out_dir}/README.md (claims table), figures and curves beside it")


if __name__ == "__main__":
    main()
