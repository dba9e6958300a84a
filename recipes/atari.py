"""Hybrid (or baseline) training on an Atari game from recorded expert states.

    python recipes/atari_expert.py env.game=Pong out_dir=experts/pong           # 1. expert (plain A2C)
    python recipes/atari_demos.py expert=experts/pong/model.pt out=demos/pong   # 2. state-only demos
    python recipes/atari.py env.game=Pong demo.path=demos/pong                  # 3. the hybrid agent

Options: recipes/config/atari.yaml, whose schema (every setting, its default and what it does)
is AtariConfig in torchrl_hybrid/families/atari.py; `--cfg job` prints them all.
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig, OmegaConf

from torchrl_hybrid.configs import register_configs
from torchrl_hybrid.families.atari import atari_config, train_atari
from torchrl_hybrid.utils.process import configure_process

register_configs()  # the schemas recipes/config/*.yaml start from


def run(cfg: DictConfig, **overrides) -> None:
    raw = OmegaConf.to_container(cfg, resolve=True)
    raw.pop("hydra", None)
    raw.update(overrides)
    try:
        config = atari_config(raw)
        configure_process(config.threads)
        summary = train_atari(config)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    print(
        f"\n{summary['game']} {summary['variant']} seed {summary['seed']}: last mean episode score "
        f"{summary['final_return']}, {summary['frames']} frames at {summary['frames_per_s']:.0f} frames/s"
        + (
            f"\nevaluation: mean score {summary['eval_return']:.1f} over {summary['evaluation']['episodes']} episodes"
            if summary.get("eval_return") is not None
            else ""
        )
        + f"\nplot: {raw['out_dir']}/learning_curve.png   curve: {raw['out_dir']}/metrics.csv"
    )


@hydra.main(config_path="config", config_name="atari", version_base=None)
def main(cfg: DictConfig) -> None:
    run(cfg)


if __name__ == "__main__":
    main()
