"""Train the hybrid agent (or a baseline) from expert state sequences on any env of the
one run assembly: gymnasium envs with discrete actions and discrete states (Taxi,
FrozenLake, CliffWalking) or vector observations (CartPole), and Atari games.

    python recipes/train.py                                        # Taxi, the paper's agent (= recipes/taxi.py)
    python recipes/train.py --config-name frozenlake8x8            # FrozenLake 8x8, not slippery
    python recipes/train.py --config-name cartpole variant=a2c out_dir=experts/cartpole
    python recipes/train.py --config-name cartpole demo.expert=experts/cartpole/model.pt
    python recipes/train.py --config-name atari env.game=Pong demo.path=demos/pong  # = recipes/atari.py

Options: recipes/config/taxi.yaml and recipes/config/atari.yaml (their schemas, GymConfig and
AtariConfig, document every one; `--cfg job` prints them) and
the presets beside them. Atari's expert, demo and evaluation steps have their own recipes
(recipes/atari_expert.py, atari_demos.py, atari_eval.py).
"""

from __future__ import annotations

import sys

import atari  # recipes/atari.py
import hydra
import taxi  # recipes/taxi.py
from omegaconf import DictConfig

from torchrl_hybrid.utils.files import out_dir_from_overrides, out_dir_problem


@hydra.main(config_path="config", config_name="taxi", version_base=None)
def main(cfg: DictConfig) -> None:
    (atari if "game" in cfg.env else taxi).run(cfg)  # the env family the config describes


def check_out_dir(argv: list[str]) -> None:
    """An out_dir that is a file (or inside one) is refused here, in one line, before Hydra
    makes its run folder there (hydra.run.dir is ${out_dir}) and fails with a traceback."""
    out = out_dir_from_overrides(argv)
    problem = out_dir_problem(out) if out else None
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    check_out_dir(sys.argv[1:])
    main()
