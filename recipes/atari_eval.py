"""Play a trained Atari policy for whole episodes and report its raw game score.

    python recipes/atari_eval.py checkpoint=results/atari/expert_pong/model.pt episodes=16

Writes eval.json beside the checkpoint (or to ``out``). Options: recipes/config/atari_eval.yaml.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig
from omegaconf.errors import MissingMandatoryValue

from torchrl_hybrid.families.atari import evaluate_atari, load_expert
from torchrl_hybrid.utils.process import configure_process


@hydra.main(config_path="config", config_name="atari_eval", version_base=None)
def main(cfg: DictConfig) -> None:
    configure_process(None)
    try:
        actor, ckpt = load_expert(cfg.checkpoint, cfg.device)
        game = ckpt["config"]["env"]["game"]
        result = evaluate_atari(
            actor,
            game,
            ckpt["preprocessing"],
            episodes=cfg.episodes,
            num_envs=cfg.num_envs,
            seed=cfg.seed,
            deterministic=cfg.deterministic,
            progress=cfg.progress,
        )
    except MissingMandatoryValue as err:
        print(f"error: {err.full_key}=... is required (see recipes/config/atari_eval.yaml)", file=sys.stderr)
        sys.exit(2)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    result.update(game=game, checkpoint=str(cfg.checkpoint), seed=cfg.seed)
    out = Path(cfg.out) if cfg.out else Path(cfg.checkpoint).with_name("eval.json")
    out.write_text(json.dumps(result, indent=2))
    print(
        f"\n{game}: mean score {result['mean']:.1f} ± {result['std'] or 0:.1f} over {result['episodes']} episodes "
        f"({'greedy' if cfg.deterministic else 'sampled'} actions); {out}"
    )


if __name__ == "__main__":
    main()
