"""Variants x seeds of one run config of the gymnasium pipeline (any preset), then a
curve file, figure, table and README in ``out_dir``.

    python recipes/compare.py --config-name cartpole out_dir=results/cartpole/compare \
        demo.expert=results/cartpole/expert/model.pt +compare.seeds=[0,1,2,3,4]
    python recipes/compare.py --config-name frozenlake8x8 out_dir=results/frozenlake_8x8/torchrl

The run settings are those of recipes/train.py (recipes/config/taxi.yaml and its presets);
``+compare.variants=[...]`` (default [a2c, hybrid_dual]; variants or named arms, in
recipes/config/arms/gym.yaml, e.g. hybrid_dual_clip_apart), ``+compare.arms={name:
{variant: ..., base: ..., <settings>}}`` (arms of your own), ``+compare.seeds=[...]``
(default [0, 1, 2]) and ``+compare.workers=N`` (default 2) choose the runs;
``+compare.analyse_only=true`` starts no run and tabulates the finished ones (each arm
with the seeds it has); ``+compare.launcher=ray`` runs them as Ray tasks (``+compare.address=<cluster>`` joins an
existing cluster; without it a local one starts). Finished runs are kept; an interrupted
one resumes from its checkpoint. Runs in ``out_dir`` made with other settings are refused,
each difference named (``overwrite=true`` runs them again with the new settings); a folder
that holds something other than a comparison is refused.
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig, OmegaConf

from torchrl_hybrid.configs import register_configs
from torchrl_hybrid.experiments.gym_compare import GymCompareConfig, run_gym_compare
from torchrl_hybrid.utils.process import configure_process

register_configs()  # the schema of taxi.yaml and its presets (compare.* is added with +)


@hydra.main(config_path="config", config_name="taxi", version_base=None)
def main(cfg: DictConfig) -> None:
    raw = OmegaConf.to_container(cfg, resolve=True)
    raw.pop("hydra", None)
    options = raw.pop("compare", None) or {}
    out_dir = raw.pop("out_dir")
    overwrite = bool(raw.pop("overwrite", False))  # the study's: rerun the runs made with other settings
    for k in ("variant", "seed", "resume"):  # set per run by the comparison
        raw.pop(k, None)
    in_process = options.get("workers", 2) == 1 and options.get("launcher", "local") == "local"
    configure_process(raw.get("threads") if in_process else None)  # workers=1: the runs train here
    try:
        known = ("variants", "arms", "seeds", "workers", "launcher", "address", "max_retries", "analyse_only")
        unknown = set(options) - set(known)
        if unknown:
            raise ValueError(f"unknown compare option(s) {sorted(unknown)}; known: {', '.join(known)}")
        # the README's Rerun line: without analyse_only, which would only redraw (dropping it runs the rest)
        command = " ".join(["python recipes/compare.py", *(a for a in sys.argv[1:] if "compare.analyse_only" not in a)])
        run_gym_compare(GymCompareConfig(base=raw, out_dir=out_dir, command=command, overwrite=overwrite, **options))
    except (ValueError, TypeError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    print(f"\nresults: {out_dir}/README.md, comparison.png, curves.csv, summary.csv")


if __name__ == "__main__":
    main()
