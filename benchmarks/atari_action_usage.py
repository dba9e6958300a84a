"""Which actions does a trained Atari policy take, overall and right after a lost life?

    python benchmarks/atari_action_usage.py results/atari/compare/Breakout/hybrid_dual_s1/model.pt ...

Plays each checkpoint's policy (sampling, as in training) in 4 envs for ``--steps``
steps and prints the action frequencies overall and over the first 20 steps after
each lost life (where Breakout needs FIRE to serve again). Action ids are the
game's minimal action set (Breakout: 0 NOOP, 1 FIRE, 2 RIGHT, 3 LEFT). A smoke run:
``--steps 5``.
"""

from __future__ import annotations

import argparse
from collections import Counter

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_hybrid.envs.atari import AtariEnv
from torchrl_hybrid.families.atari import load_expert


def action_usage(path: str, steps: int = 1500, num_envs: int = 4, seed: int = 123, window: int = 20) -> dict:
    actor, ckpt = load_expert(path)
    env = AtariEnv(ckpt["config"]["env"]["game"], num_envs, seed=seed, num_threads=1)
    td = env.reset()
    lives = td["lives"].clone()
    overall, after = Counter(), Counter()
    since = torch.full((num_envs,), 10**9)
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        for _ in range(steps):
            td = actor(td)
            for i, a in enumerate(td["action"].tolist()):
                overall[a] += 1
                if since[i] < window:
                    after[a] += 1
            td, root = env.step_and_maybe_reset(td)
            since += 1
            since[(td["next", "lives"] < lives).flatten()] = 0
            lives, td = root["lives"].clone(), root
    env.close()
    freq = lambda c: {a: round(c[a] / max(sum(c.values()), 1), 3) for a in range(env.n_actions)}  # noqa: E731
    return {"overall": freq(overall), "after_life_lost": freq(after), "after_samples": sum(after.values())}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoints", nargs="+", help="model.pt files written by train_atari")
    p.add_argument("--steps", type=int, default=1500)
    a = p.parse_args()
    if a.steps < 1:
        p.error(f"--steps must be >= 1, got {a.steps}")
    for path in a.checkpoints:  # every checkpoint is readable before the first one plays
        try:
            load_expert(path)
        except (ValueError, FileNotFoundError) as err:
            p.error(str(err))
    torch.set_num_threads(1)
    for path in a.checkpoints:
        u = action_usage(path, a.steps)
        print(
            f"{path}\n  overall:                        {u['overall']}\n"
            f"  first 20 steps after a lost life: {u['after_life_lost']} ({u['after_samples']} samples)"
        )


if __name__ == "__main__":
    main()
