"""Train the hybrid agent (or a baseline) from expert state sequences on any env of the
one run assembly: gymnasium envs with discrete actions and discrete states (Taxi,
FrozenLake, CliffWalking) or vector observations (CartPole), and Atari games.

    python recipes/train.py                                        # Taxi, the paper's agent (= recipes/taxi.py)
    python recipes/train.py --config-name frozenlake8x8            # FrozenLake 8x8, not slippery
    python recipes/train.py --config-name cartpole variant=a2c out_dir=experts/cartpole
    python recipes/train.py --config-name cartpole demo.expert=experts/cartpole/model.pt
    python recipes/train.py --config-name atari env.game=Pong demo.path=demos/pong  # = recipes/atari.py

Options: recipes/config/taxi.yaml and recipes/config/atari.yaml (their schemas, TaxiConfig and
AtariConfig, document every one; `--cfg job` prints them) and
the presets beside them. Atari's expert, demo and evaluation steps have their own recipes
(recipes/atari_expert.py, atari_demos.py, atari_eval.py).
"""
from __future__ import annotations

import hydra
from omegaconf import DictConfig

import atari  # recipes/atari.py
import taxi  # recipes/taxi.py


@hydra.main(config_path="config", config_name="taxi", version_base=None)
def main(cfg: DictConfig) -> None:
    (atari if "game" in cfg.env else taxi).run(cfg)  # the env family the config describes


if __name__ == "__main__":
    main()
