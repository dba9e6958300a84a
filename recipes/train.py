"""Train the hybrid agent (or a baseline) on any gymnasium env with discrete actions
and discrete states (Taxi, FrozenLake, CliffWalking) or vector observations (CartPole),
from expert state sequences.

    python recipes/train.py                                        # Taxi, the paper's agent (= recipes/taxi.py)
    python recipes/train.py --config-name frozenlake8x8            # FrozenLake 8x8, not slippery
    python recipes/train.py --config-name cartpole variant=a2c out_dir=experts/cartpole
    python recipes/train.py --config-name cartpole demo.expert=experts/cartpole/model.pt

Options: recipes/config/taxi.yaml (every one documented) and the presets beside it.
Atari frames have their own recipes (recipes/atari*.py).
"""
from __future__ import annotations

import hydra
from omegaconf import DictConfig

from taxi import run  # recipes/taxi.py


@hydra.main(config_path="config", config_name="taxi", version_base=None)
def main(cfg: DictConfig) -> None:
    run(cfg)


if __name__ == "__main__":
    main()
