"""Atari training throughput, measured side by side in one run on one game.

    python benchmarks/atari_throughput.py --game Pong --steps 16000                 # CPU (2 torch threads)
    python benchmarks/atari_throughput.py --device cuda --threads 16 --num-envs 64  # a GPU machine
    python benchmarks/atari_throughput.py --steps 10 --num-envs 2 --threads 1 --no-sb3  # a smoke run

Trains, with ``--num-envs`` environments each (the paper's 16 by default), our
``a2c`` and ``hybrid_dual`` variants (recipes/atari.py's pipeline: AtariCollector,
BC term on from the start so that its cost counts) and Stable-Baselines3's A2C
(``CnnPolicy``, its Atari wrappers, on the same device; an optional,
benchmark-only dependency: ``pip install stable-baselines3
opencv-python-headless``), and prints agent steps/s (x4 = game frames/s) and the
ratios. ``--all`` adds our ``a2c`` with TorchRL's generic ``Collector`` (the
reference path) and with the games split into 2 pipelined groups.

It also prints the project's own floor on this machine: ale-py stepping the same
games with random actions, and the paper's CNN alone (no-grad forward of the
envs' frames per step, forward + backward of a batch), summed per batch.

Setup (env creation, demo recording) is not timed, nor is the inverse model's
accuracy column (a logging diagnostic, ``logger.accuracy_pairs=0``: off).
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

import torch

logging.getLogger("torchrl").setLevel(logging.WARNING)


def bench_config(
    variant: str,
    game: str,
    steps: int,
    out: Path,
    demos: Path | None,
    threads: int,
    *,
    device: str = "cpu",
    num_envs: int = 16,
    collector: dict | None = None,
):
    """The measured run: BC on from the start, no logging, diagnostics or checkpoints."""
    from torchrl_hybrid.families.atari import atari_config

    cfg = {
        "variant": variant,
        "total_frames": 4 * steps,
        "out_dir": str(out / variant),
        "threads": threads,
        "overwrite": True,  # a scratch folder, measured again by --all
        "device": device,
        "env": {"game": game, "num_envs": num_envs, "num_threads": threads},
        "collector": collector or {},
        "loss": {"bc_start_frames": 0},
        "logger": {
            "progress_bar": False,
            "checkpoint": False,
            "backend": "none",
            "log_every_frames": 10**9,
            "accuracy_pairs": 0,
        },
    }
    if demos is not None:
        cfg["demo"] = {"path": str(demos)}
    return atari_config(cfg)


def bench_demos(game: str, tmp: Path, num_envs: int = 16) -> Path:
    """Demos for the hybrid's BC term from an untrained policy (the cost is what matters;
    ``num_envs``: the untrained expert's envs, at most 16)."""
    from torchrl_hybrid.families.atari import atari_config, record_demos, train_atari

    train_atari(
        atari_config(
            {
                "variant": "a2c",
                "total_frames": 320,
                "out_dir": str(tmp / "expert"),
                "device": "cpu",
                "env": {"game": game, "num_envs": min(num_envs, 16)},
                "logger": {"progress_bar": False, "checkpoint": False, "backend": "none"},
            }
        )
    )
    record_demos(
        tmp / "expert" / "model.pt",
        tmp / "demos",
        num_trajectories=8,
        num_envs=8,
        max_steps=200,
        progress=False,
        device="cpu",
    )
    return tmp / "demos"


def ours(variant: str, game: str, steps: int, out: Path, demos: Path | None, threads: int, **kw) -> float:
    from torchrl_hybrid.families.atari import train_atari

    cfg = bench_config(variant, game, steps, out, demos, threads, **kw)
    return train_atari(cfg)["frames_per_s"] / 4  # game frames/s -> agent steps/s


def sb3(game: str, steps: int, threads: int, device: str, num_envs: int) -> float | None:
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
    env = VecFrameStack(make_atari_env(f"{game}NoFrameskip-v4", n_envs=num_envs, seed=0), n_stack=4)
    model = A2C("CnnPolicy", env, verbose=0, device=device, seed=0)
    model.learn(total_timesteps=10 * num_envs)  # warm-up
    t0 = time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=True)
    return steps / (time.perf_counter() - t0)


def floors(
    game: str, threads: int, device: str, num_envs: int, n_steps: int = 5, channels_last_too: bool = False
) -> dict[str, float]:
    """Milliseconds per batch (``num_envs`` x ``n_steps`` agent steps) of ale-py alone
    and of the bare CNN passes the learner cannot avoid (``channels_last_too``: also
    the forward + backward pass with contiguous, not channels-last, convolutions)."""
    from ale_py.vector_env import AtariVectorEnv

    from torchrl_hybrid.envs.atari import _rom_name
    from torchrl_hybrid.modules import AtariEncoder

    torch.set_num_threads(threads)
    env = AtariVectorEnv(
        _rom_name(game),
        num_envs,
        num_threads=threads,
        autoreset_mode="SameStep",
        noop_max=30,
        frameskip=4,
        stack_num=4,
        img_height=84,
        img_width=84,
        grayscale=True,
        maxpool=True,
    )
    env.reset(seed=0)
    n = env.single_action_space.n
    t = time.perf_counter()
    for _ in range(200):
        env.step(torch.randint(n, (num_envs,)).numpy())
    ale = (time.perf_counter() - t) / 200 * n_steps * 1000
    env.close()
    dev = torch.device(device)
    enc = AtariEncoder().to(dev)
    enc.reuse_features = False
    x_step = torch.randint(0, 255, (num_envs, 4, 84, 84), dtype=torch.uint8, device=dev)
    x_batch = torch.randint(0, 255, (num_envs * n_steps, 4, 84, 84), dtype=torch.uint8, device=dev)

    def bench(f, k):
        for _ in range(3):
            f()
        if dev.type == "cuda":
            torch.cuda.synchronize()
        t = time.perf_counter()
        for _ in range(k):
            f()
        if dev.type == "cuda":
            torch.cuda.synchronize()
        return (time.perf_counter() - t) / k * 1000

    with torch.no_grad():
        fwd = bench(lambda: enc(x_step), 50)

    def train(e):
        def f():
            e.zero_grad()
            e(x_batch).sum().backward()

        return f

    out = {
        "ale-py alone (random actions)": ale,
        f"CNN no-grad forward of {num_envs}, x{n_steps}": n_steps * fwd,
        f"CNN forward + backward of {num_envs * n_steps}": bench(train(enc), 20),
    }
    if channels_last_too:
        plain = AtariEncoder(channels_last=False).to(dev)
        plain.reuse_features = False
        out["  same, contiguous (not channels-last)"] = bench(train(plain), 20)
    return out


def check_args(p: argparse.ArgumentParser, a: argparse.Namespace, num_envs: int) -> str:
    """Refuses, before any run, settings that would fail in one; returns the device."""
    from torchrl_hybrid.envs.atari import action_names
    from torchrl_hybrid.utils.device import resolve_device

    for name in ("threads", "num_envs"):
        if getattr(a, name, 1) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(a, name)}")
    if a.steps < 5 * num_envs:
        p.error(f"--steps must be at least one batch ({num_envs} envs x 5 steps = {5 * num_envs}), got {a.steps}")
    try:
        action_names(a.game)
        return str(resolve_device(a.device))
    except ValueError as err:
        p.error(str(err))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--game", default="Pong")
    p.add_argument("--steps", type=int, default=16_000, help="agent steps per measurement (x4 game frames)")
    p.add_argument("--threads", type=int, default=2, help="torch threads and ALE threads")
    p.add_argument("--device", default="cpu", help="cpu | cuda | auto: where our learner and SB3's run")
    p.add_argument("--num-envs", type=int, default=16)
    p.add_argument("--all", action="store_true", help="also our a2c on TorchRL's Collector and with 2 env groups")
    p.add_argument("--no-sb3", action="store_true")
    a = p.parse_args()
    device = check_args(p, a, a.num_envs)
    torch.set_num_threads(a.threads)  # --threads: torch's too, for every measurement (not only SB3's and the floors')
    kw = {"device": device, "num_envs": a.num_envs}
    with tempfile.TemporaryDirectory() as tmp:  # scratch: the runs, the demos
        tmp = Path(tmp)
        demos = bench_demos(a.game, tmp, a.num_envs)
        rows = [
            ("ours: a2c", ours("a2c", a.game, a.steps, tmp, None, a.threads, **kw)),
            ("ours: hybrid_dual", ours("hybrid_dual", a.game, a.steps, tmp, demos, a.threads, **kw)),
        ]
        if a.all:
            rows.append(
                (
                    "ours: a2c, TorchRL Collector",
                    ours("a2c", a.game, a.steps, tmp, None, a.threads, **kw, collector={"backend": "torchrl"}),
                )
            )
            rows.append(
                (
                    "ours: a2c, 2 env groups",
                    ours("a2c", a.game, a.steps, tmp, None, a.threads, **kw, collector={"env_groups": 2}),
                )
            )
    base = None if a.no_sb3 else sb3(a.game, a.steps, a.threads, device, a.num_envs)
    if base is not None:
        rows.append((f"Stable-Baselines3 A2C ({device})", base))
    fl = floors(a.game, a.threads, device, a.num_envs)
    floor_ms = sum(fl.values())  # ALE + collection forward + learner forward/backward
    print(
        f"\n{a.game}, {a.num_envs} envs x 5 steps a batch, {a.steps:,} agent steps each, {a.threads} threads, "
        f"learner on {device}"
    )
    for name, v in rows:
        print(f"  {name:34s} {v:8,.0f} agent steps/s  {4 * v:9,.0f} game frames/s")
    if base is not None:
        for name, v in rows:
            if name.startswith("ours"):
                print(f"  {name} / SB3 A2C: {v / base:.2f}x")
    print(f"floor per batch of {a.num_envs * 5} agent steps (same machine, same run):")
    for k, v in fl.items():
        print(f"  {k:34s} {v:8.1f} ms")
    print(f"  {'sum = floor':34s} {floor_ms:8.1f} ms = {a.num_envs * 5 * 1000 / floor_ms:,.0f} agent steps/s")
    for name, v in rows[:2]:
        print(f"  {name} / floor: {v / (a.num_envs * 5 * 1000 / floor_ms):.2f}")


if __name__ == "__main__":
    main()
