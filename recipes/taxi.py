"""Train the hybrid agent (or a baseline) on Taxi from expert state sequences.

    python recipes/taxi.py                       # the paper's agent, defaults
    python recipes/taxi.py variant=a2c seed=3    # a baseline
    python recipes/taxi.py demo.eta=0.5 out_dir=/tmp/eta05

Every option is documented in the schema of recipes/config/taxi.yaml (GymConfig in
torchrl_hybrid/families/gym.py; `--cfg job` prints them all). Writes metrics.csv,
summary.json, learning_curve.png, model.pt, config.json and a TorchRL checkpoint/ folder
into ``out_dir`` (``resume=true`` continues it, ``overwrite=true`` replaces it).
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig, OmegaConf

from torchrl_hybrid.configs import register_configs
from torchrl_hybrid.families.gym import config_from_dict, train_gym
from torchrl_hybrid.utils.process import configure_process

register_configs()  # the schemas recipes/config/*.yaml start from


def run(cfg: DictConfig) -> None:
    """Trains one run from a Hydra config (also the body of recipes/train.py)."""
    raw = OmegaConf.to_container(cfg, resolve=True)
    raw.pop("hydra", None)
    try:
        config = config_from_dict(
            raw
        ).validate()  # every setting checked before out_dir is touched (also engine=batched)
        configure_process(config.threads)
        if config.engine == "batched":
            from torchrl_hybrid.families.gym_batched import train_taxi_batched
            from torchrl_hybrid.utils.files import prepare_out_dir

            with prepare_out_dir(config.out_dir, overwrite=config.overwrite):  # the same out_dir rules
                summary = train_taxi_batched([config])[0]
        else:
            summary = train_gym(config)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    out = config.out_dir
    print(
        f"\n{summary['variant']} seed {summary['seed']}: final greedy return "
        f"{summary['final_return']:.2f} over {summary['final_eval_episodes']} episodes"
        + (f" (expert {summary['optimal_return']:.2f})" if summary["optimal_return"] is not None else "")
        + (
            f", inverse-model accuracy on the demos {summary['idm_accuracy_expert']:.1%}"
            if summary["idm_accuracy_expert"] is not None
            else ""
        )
        + f"\n{summary['frames']} frames in {summary['train_time_s']:.0f} s ({summary['frames_per_s']:.0f} frames/s)"
        f"\nplot: {out}/learning_curve.png   curve: {out}/metrics.csv   summary: {out}/summary.json"
    )


@hydra.main(config_path="config", config_name="taxi", version_base=None)
def main(cfg: DictConfig) -> None:
    run(cfg)


if __name__ == "__main__":
    main()
