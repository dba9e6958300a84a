"""Play an Atari expert and record state-only trajectories as a dataset.

python recipes/atari_demos.py expert=experts/pong/model.pt out=demos/pong num_trajectories=100
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig
from omegaconf.errors import MissingMandatoryValue

from torchrl_hybrid.families.atari import record_demos
from torchrl_hybrid.utils.process import configure_process


@hydra.main(config_path="config", config_name="atari_demos", version_base=None)
def main(cfg: DictConfig) -> None:
    configure_process(None)
    try:
        meta = record_demos(
            cfg.expert,
            cfg.out,
            num_trajectories=cfg.num_trajectories,
            num_envs=cfg.num_envs,
            seed=cfg.seed,
            deterministic=cfg.deterministic,
            max_steps=cfg.max_steps,
            cut=cfg.cut,
            progress=cfg.progress,
            device=cfg.device,
            overwrite=cfg.overwrite,
        )
    except MissingMandatoryValue as err:
        print(f"error: {err.full_key}=... is required (see recipes/config/atari_demos.yaml)", file=sys.stderr)
        sys.exit(2)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    n = meta["num_trajectories"]
    print(
        f"\n{n} {meta['game']} trajectories, {sum(meta['lengths'])} pairs, mean score "
        f"{sum(meta['returns']) / n:.1f}, saved to {cfg.out}"
    )


if __name__ == "__main__":
    main()
