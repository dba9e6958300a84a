"""hybrid_dual vs a2c (or any variants) on several Atari games and seeds, then one
curve file, figure and summary table per game under ``out_dir/<game>/``, and one figure of
every game analysed in ``out_dir`` so far (``out_dir/overview.png``), and of each robust
option's measured effect where it has one (``out_dir/effects.png``).

    python recipes/atari_expert.py env.game=Pong out_dir=experts/pong
    python recipes/atari_demos.py expert=experts/pong/model.pt out=demos/pong
    python recipes/atari_compare.py games=[Pong] +demos.Pong=demos/pong

Options: recipes/config/atari_compare.yaml.
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig, OmegaConf

from torchrl_hybrid.experiments.atari_compare import CompareConfig, run_compare
from torchrl_hybrid.utils.process import configure_process


@hydra.main(config_path="config", config_name="atari_compare", version_base=None)
def main(cfg: DictConfig) -> None:
    raw = OmegaConf.to_container(cfg, resolve=True)
    raw.pop("hydra", None)
    try:
        cfg = CompareConfig(**raw)
        configure_process(cfg.process_threads())  # workers=1: the runs train in this process
        run_compare(cfg)
    except (ValueError, TypeError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    print(
        f"\nresults: {raw['out_dir']}/<game>/comparison.png, curves.csv, summary.csv, summary.md; "
        f"{raw['out_dir']}/overview.png (every game), effects.png (each option's effect, where measured)"
    )


if __name__ == "__main__":
    main()
