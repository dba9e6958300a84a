"""Atari training throughput, measured side by side in one run on one game.

    python benchmarks/atari_throughput.py --game Pong --steps 16000

Trains, with 16 environments each, our ``a2c`` and ``hybrid_dual`` variants
(recipes/atari.py's pipeline, the BC term on from the start so that its cost
counts) and Stable-Baselines3's A2C (``CnnPolicy``, its Atari wrappers; an
optional, benchmark-only dependency: ``pip install stable-baselines3
opencv-python-headless``), and prints agent steps/s (x4 = game frames/s) and the
ratios. Setup (env creation, demo recording) is not timed.
"""
from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

import torch

logging.getLogger("torchrl").setLevel(logging.WARNING)


def bench_config(variant: str, game: str, steps: int, out: Path, demos: Path | None, threads: int):
    """The measured run: 16 envs, BC on from the start, no logging or checkpoints."""
    from torchrl_hybrid.trainers.atari import atari_config

    cfg = {"variant": variant, "total_frames": 4 * steps, "out_dir": str(out / variant), "threads": threads,
           "env": {"game": game, "num_envs": 16, "num_threads": threads},
           "loss": {"bc_start_frames": 0},
           "logger": {"progress_bar": False, "checkpoint": False, "backend": "none", "log_every_frames": 10**9}}
    if demos is not None:
        cfg["demo"] = {"path": str(demos)}
    return atari_config(cfg)


def bench_demos(game: str, tmp: Path) -> Path:
    """Demos for the hybrid's BC term from an untrained policy (the cost is what matters)."""
    from torchrl_hybrid.trainers.atari import atari_config, record_demos, train_atari

    train_atari(atari_config({"variant": "a2c", "total_frames": 320, "out_dir": str(tmp / "expert"),
                              "env": {"game": game, "num_envs": 16},
                              "logger": {"progress_bar": False, "checkpoint": False, "backend": "none"}}))
    record_demos(tmp / "expert" / "model.pt", tmp / "demos", num_trajectories=8, num_envs=8, max_steps=200,
                 progress=False)
    return tmp / "demos"


def ours(variant: str, game: str, steps: int, out: Path, demos: Path | None, threads: int) -> float:
    from torchrl_hybrid.trainers.atari import train_atari

    cfg = bench_config(variant, game, steps, out, demos, threads)
    return train_atari(cfg)["frames_per_s"] / 4  # game frames/s -> agent steps/s


def sb3(game: str, steps: int, threads: int) -> float | None:
    try:
        import ale_py
        import gymnasium as gym
        from stable_baselines3 import A2C
        from stable_baselines3.common.env_util import make_atari_env
        from stable_baselines3.common.vec_env import VecFrameStack
    except ImportError as err:
        print(f"Stable-Baselines3 not measured ({err}); pip install stable-baselines3 opencv-python-headless")
        return None
    gym.register_envs(ale_py)
    torch.set_num_threads(threads)
    env = VecFrameStack(make_atari_env(f"{game}NoFrameskip-v4", n_envs=16, seed=0), n_stack=4)
    model = A2C("CnnPolicy", env, verbose=0, device="cpu", seed=0)
    model.learn(total_timesteps=160)  # warm-up
    t0 = time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=True)
    return steps / (time.perf_counter() - t0)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--game", default="Pong")
    p.add_argument("--steps", type=int, default=16_000, help="agent steps per measurement (x4 game frames)")
    p.add_argument("--threads", type=int, default=2, help="torch threads (and ALE threads for ours)")
    a = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        demos = bench_demos(a.game, tmp)
        rows = [("ours: a2c", ours("a2c", a.game, a.steps, tmp, None, a.threads)),
                ("ours: hybrid_dual", ours("hybrid_dual", a.game, a.steps, tmp, demos, a.threads))]
    base = sb3(a.game, a.steps, a.threads)
    if base is not None:
        rows.append(("Stable-Baselines3 A2C", base))
    print(f"\n{a.game}, 16 envs, {a.steps:,} agent steps each, {a.threads} torch threads")
    for name, v in rows:
        print(f"  {name:24s} {v:8,.0f} agent steps/s  {4 * v:9,.0f} game frames/s")
    if base is not None:
        for name, v in rows[:2]:
            print(f"  {name} / SB3 A2C: {v / base:.2f}x")


if __name__ == "__main__":
    main()
