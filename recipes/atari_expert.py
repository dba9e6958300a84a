"""Train a plain A2C expert on an Atari game and save its checkpoint (model.pt,
with its config), its learning curve and its summary (last mean episode score).

    python recipes/atari_expert.py env.game=Pong out_dir=experts/pong
"""

from __future__ import annotations

import hydra
from atari import run  # recipes/atari.py
from omegaconf import DictConfig


@hydra.main(config_path="config", config_name="atari_expert", version_base=None)
def main(cfg: DictConfig) -> None:
    run(cfg, variant="a2c")


if __name__ == "__main__":
    main()
