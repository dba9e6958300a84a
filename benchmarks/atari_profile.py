"""Where the time of an Atari training run goes, per collected batch.

    python benchmarks/atari_profile.py --game Pong --steps 8000
    python benchmarks/atari_profile.py --steps 10 --num-envs 2 --threads 1        # a smoke run

Builds the same run as ``recipes/atari.py`` (:func:`build_atari`: AtariCollector,
collection features kept for the learner), times its parts with wall-clock
wrappers (no profiler overhead) while it trains, and prints
milliseconds per batch of 16 envs (``--num-envs``) x 5 steps = 80 agent steps for ``a2c`` and
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
from atari_throughput import bench_config, bench_demos, check_args, floors  # benchmarks/ (the script's own folder)

logging.getLogger("torchrl").setLevel(logging.WARNING)


def _timed(fn, timers, name, cuda: bool = False):
    # on CUDA, kernels run asynchronously: synchronise around each part so that its
    # time is its own (this slows the run a little; the breakdown is what matters)
    def wrapper(*args, **kwargs):
        if cuda:
            torch.cuda.synchronize()
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            if cuda:
                torch.cuda.synchronize()
            timers[name] += time.perf_counter() - t

    return wrapper


def profile_run(
    variant: str,
    game: str,
    steps: int,
    out: Path,
    demos: Path | None,
    threads: int,
    device: str = "cpu",
    num_envs: int = 16,
) -> dict:
    from torchrl_hybrid.families.atari import build_atari

    run = build_atari(bench_config(variant, game, steps, out, demos, threads, device=device, num_envs=num_envs))
    timers: dict[str, float] = defaultdict(float)
    cuda = run.device.type == "cuda"
    collector = run.trainer.collector
    for env in collector.envs:
        env.send = _timed(env.send, timers, "env: ale-py step (send + recv)", cuda)
        env.recv = _timed(env.recv, timers, "env: ale-py step (send + recv)", cuda)
    collector._policy_step = _timed(collector._policy_step, timers, "policy: CNN + heads + sampling", cuda)
    collector.rollout = _timed(collector.rollout, timers, "collection (rollout) in all", cuda)
    run.loss.forward = _timed(run.loss.forward, timers, "loss forward (A2C + IDM + BC)", cuda)
    opt = run.trainer.optimizer
    opt.step = _timed(opt.step, timers, "RMSprop step", cuda)
    orig_backward = torch.Tensor.backward
    torch.Tensor.backward = _timed(orig_backward, timers, "backward", cuda)
    try:
        t0 = time.perf_counter()
        run.trainer.train()
        total = time.perf_counter() - t0
    finally:
        torch.Tensor.backward = orig_backward
    batches = run.trainer.collected_frames / 4 / run.cfg.frames_per_batch
    out = {k: 1000 * v / batches for k, v in timers.items()}
    out["total"] = 1000 * total / batches
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--game", default="Pong")
    p.add_argument("--steps", type=int, default=8000, help="agent steps per run (x4 game frames)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--device", default="cpu", help="cpu | cuda | auto: where the learner runs")
    p.add_argument("--num-envs", type=int, default=16)
    a = p.parse_args()
    device = check_args(p, a, a.num_envs)
    torch.set_num_threads(a.threads)  # --threads: torch's too, for every measurement (not only SB3's and the floors')
    batch = 5 * a.num_envs
    with tempfile.TemporaryDirectory() as tmp:  # scratch: the runs, the demos
        tmp = Path(tmp)
        demos = bench_demos(a.game, tmp, a.num_envs)
        runs = {
            "a2c": profile_run("a2c", a.game, a.steps, tmp, None, a.threads, device, a.num_envs),
            "hybrid_dual": profile_run("hybrid_dual", a.game, a.steps, tmp, demos, a.threads, device, a.num_envs),
        }
    fl = floors(a.game, a.threads, device, a.num_envs, channels_last_too=True)
    print(
        f"\n{a.game}: milliseconds per batch of {batch} agent steps ({a.num_envs} envs x 5), {a.steps:,} steps "
        f"a run, learner on {device}"
    )
    keys = [
        "collection (rollout) in all",
        "env: ale-py step (send + recv)",
        "policy: CNN + heads + sampling",
        "loss forward (A2C + IDM + BC)",
        "backward",
        "RMSprop step",
    ]
    print(f"  {'':34s} {'a2c':>8s} {'hybrid_dual':>12s}")
    for k in keys:
        label = ("  - " if k.startswith(("env", "policy")) else "") + k
        print(f"  {label:34s} {runs['a2c'].get(k, 0):8.1f} {runs['hybrid_dual'].get(k, 0):12.1f}")
    for name in ("a2c", "hybrid_dual"):
        r = runs[name]
        r["rest"] = r["total"] - sum(r.get(k, 0) for k in keys if not k.startswith(("env", "policy")))
    print(
        f"  {'rest (trainer, hooks, clip, demos)':34s} {runs['a2c']['rest']:8.1f} {runs['hybrid_dual']['rest']:12.1f}"
    )
    print(f"  {'total':34s} {runs['a2c']['total']:8.1f} {runs['hybrid_dual']['total']:12.1f}")
    print(
        f"  {'= agent steps/s':34s} {1000 * batch / runs['a2c']['total']:8.0f} "
        f"{1000 * batch / runs['hybrid_dual']['total']:12.0f}"
    )
    print("floors (same machine, same run):")
    for k, v in fl.items():
        print(f"  {k:34s} {v:8.1f} ms")


if __name__ == "__main__":
    main()
