"""Where the time of an Atari training run goes, per collected batch.

    python benchmarks/atari_profile.py --game Pong --steps 8000

Builds the same run as ``recipes/atari.py`` (:func:`build_atari`), times its
parts with wall-clock wrappers (no profiler overhead) while it trains, and prints
milliseconds per batch of 16 envs x 5 steps = 80 agent steps for ``a2c`` and
``hybrid_dual`` (BC term on from the start), next to the floors: ale-py stepping
the same envs with no learner, and the bare CNN (no-grad forward of 16 frame
stacks, forward + backward of 80).
"""
from __future__ import annotations

import argparse
import logging
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import torch
from atari_throughput import bench_config, bench_demos  # benchmarks/ (the script's own folder)

logging.getLogger("torchrl").setLevel(logging.WARNING)


def _timed(fn, timers, name):
    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            timers[name] += time.perf_counter() - t
    return wrapper


def profile_run(variant: str, game: str, steps: int, out: Path, demos: Path | None, threads: int) -> dict:
    from torchrl_hybrid.trainers.atari import build_atari

    run = build_atari(bench_config(variant, game, steps, out, demos, threads))
    timers: dict[str, float] = defaultdict(float)
    base = run.env.base_env
    base._step = _timed(base._step, timers, "env: ale-py step + AtariEnv")
    pol = run.collection_policy
    pol.forward = _timed(pol.forward, timers, "policy: CNN + heads + sampling")
    collector = run.trainer.collector
    collector.rollout = _timed(collector.rollout, timers, "collection (rollout) in all")
    run.loss.forward = _timed(run.loss.forward, timers, "loss forward (A2C + IDM + BC)")
    opt = run.trainer.optimizer
    opt.step = _timed(opt.step, timers, "RMSprop step")
    orig_backward = torch.Tensor.backward
    torch.Tensor.backward = _timed(orig_backward, timers, "backward")
    try:
        t0 = time.perf_counter()
        run.trainer.train()
        total = time.perf_counter() - t0
    finally:
        torch.Tensor.backward = orig_backward
    run.env.close()
    batches = run.trainer.collected_frames / 4 / run.cfg.frames_per_batch
    out = {k: 1000 * v / batches for k, v in timers.items()}
    out["total"] = 1000 * total / batches
    return out


def floors(game: str, threads: int) -> dict:
    from ale_py.vector_env import AtariVectorEnv

    from torchrl_hybrid.envs.atari import _rom_name
    from torchrl_hybrid.modules import AtariEncoder

    torch.set_num_threads(threads)
    env = AtariVectorEnv(_rom_name(game), 16, num_threads=threads, autoreset_mode="SameStep", noop_max=30,
                         frameskip=4, stack_num=4, img_height=84, img_width=84, grayscale=True, maxpool=True)
    env.reset(seed=0)
    n = env.single_action_space.n
    t = time.perf_counter()
    for _ in range(200):
        env.step(torch.randint(n, (16,)).numpy())
    ale = (time.perf_counter() - t) / 200 * 5 * 1000
    env.close()
    enc = AtariEncoder()
    enc.reuse_features = False
    x16 = torch.randint(0, 255, (16, 4, 84, 84), dtype=torch.uint8)
    x80 = torch.randint(0, 255, (80, 4, 84, 84), dtype=torch.uint8)

    def bench(f, k):
        for _ in range(3):
            f()
        t = time.perf_counter()
        for _ in range(k):
            f()
        return (time.perf_counter() - t) / k * 1000

    with torch.no_grad():
        fwd16 = bench(lambda: enc(x16), 100)

    def train80(e):
        def f():
            e.zero_grad()
            e(x80).sum().backward()
        return f

    plain = AtariEncoder(channels_last=False)
    plain.reuse_features = False
    return {"ale-py alone, 5 steps of 16 envs": ale, "CNN no-grad forward of 16, x5": 5 * fwd16,
            "CNN forward + backward of 80": bench(train80(enc), 20),
            "  same, contiguous (not channels-last)": bench(train80(plain), 20)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--game", default="Pong")
    p.add_argument("--steps", type=int, default=8000, help="agent steps per run (x4 game frames)")
    p.add_argument("--threads", type=int, default=2)
    a = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        demos = bench_demos(a.game, tmp)
        runs = {"a2c": profile_run("a2c", a.game, a.steps, tmp, None, a.threads),
                "hybrid_dual": profile_run("hybrid_dual", a.game, a.steps, tmp, demos, a.threads)}
    fl = floors(a.game, a.threads)
    print(f"\n{a.game}: milliseconds per batch of 80 agent steps (16 envs x 5), {a.steps:,} steps a run")
    keys = ["collection (rollout) in all", "env: ale-py step + AtariEnv", "policy: CNN + heads + sampling",
            "loss forward (A2C + IDM + BC)", "backward", "RMSprop step"]
    print(f"  {'':34s} {'a2c':>8s} {'hybrid_dual':>12s}")
    for k in keys:
        label = ("  - " if k.startswith(("env", "policy")) else "") + k
        print(f"  {label:34s} {runs['a2c'].get(k, 0):8.1f} {runs['hybrid_dual'].get(k, 0):12.1f}")
    for name in ("a2c", "hybrid_dual"):
        r = runs[name]
        r["rest"] = r["total"] - sum(r.get(k, 0) for k in keys if not k.startswith(("env", "policy")))
    print(f"  {'rest (trainer, hooks, clip, demos)':34s} {runs['a2c']['rest']:8.1f} {runs['hybrid_dual']['rest']:12.1f}")
    print(f"  {'total':34s} {runs['a2c']['total']:8.1f} {runs['hybrid_dual']['total']:12.1f}")
    print(f"  {'= agent steps/s':34s} {80000 / runs['a2c']['total']:8.0f} {80000 / runs['hybrid_dual']['total']:12.0f}")
    print("floors (same machine, same run):")
    for k, v in fl.items():
        print(f"  {k:34s} {v:8.1f} ms")


if __name__ == "__main__":
    main()
