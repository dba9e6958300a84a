"""Taxi throughput, measured side by side in one run.

    python benchmarks/taxi_throughput.py            # ~2 minutes on a 2-core CPU
    python benchmarks/taxi_throughput.py --quick    # shorter measurements
    python benchmarks/taxi_throughput.py --seconds 0.05 --frames 32 --seeds 2 --eval-episodes 1  # a smoke run

Prints environment steps/s of TorchRL's GymEnv path and of our fast paths, and
training frames/s of one seed (TorchRL collector + trainer) and of 16 seeds
batched (the sweep's path), with their ratios. Every number is measured here, now.
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time

import torch

logging.getLogger("torchrl").setLevel(logging.WARNING)


def timed(fn, min_seconds: float) -> tuple[float, int]:
    """Runs fn() (returning a count) until min_seconds have passed; returns count/s."""
    fn()  # warm-up
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < min_seconds:
        n += fn()
    return n / (time.perf_counter() - t0), n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="shorter measurements")
    parser.add_argument("--seeds", type=int, default=16, help="agents in the batched training measurement")
    parser.add_argument(
        "--seconds", type=float, default=None, help="seconds per environment measurement (default 5, 2 with --quick)"
    )
    parser.add_argument(
        "--frames", type=int, default=None, help="frames per training measurement (default 24000, 8000 with --quick)"
    )
    parser.add_argument(
        "--eval-episodes",
        type=int,
        default=None,
        help="greedy episodes of each evaluation in the training measurements (default: the "
        "runs' own, logger.eval_episodes and logger.final_eval_episodes)",
    )
    args = parser.parse_args()
    secs = args.seconds if args.seconds is not None else (2.0 if args.quick else 5.0)
    frames = args.frames if args.frames is not None else (8_000 if args.quick else 24_000)
    if args.seeds < 1:
        parser.error(f"--seeds must be >= 1, got {args.seeds}")
    if not secs > 0:
        parser.error(f"--seconds must be > 0, got {secs}")
    torch.set_num_threads(1)

    from torchrl.envs import GymEnv, SerialEnv

    from torchrl_hybrid.envs import TabularModel, make_gym_env
    from torchrl_hybrid.families.gym import config_from_dict, train_gym
    from torchrl_hybrid.families.gym_batched import train_taxi_batched

    logger = {"progress_bar": False, "backend": "none", "checkpoint": False}
    if args.eval_episodes is not None:
        logger.update(eval_episodes=args.eval_episodes, final_eval_episodes=args.eval_episodes)

    def cfg(out_dir, **kw):
        d = {"total_frames": frames, "out_dir": out_dir, "logger": logger}
        d.update(kw)
        return config_from_dict(d)

    try:
        cfg("unused").validate()
    except ValueError as err:
        parser.error(str(err))

    rows = []
    # --- environment steps -------------------------------------------------------------
    gym1 = GymEnv("Taxi-v4", categorical_action_encoding=True)
    rows.append(
        (
            "env: torchrl GymEnv, 1 env, rollout",
            timed(lambda: gym1.rollout(200, break_when_any_done=False).numel(), secs)[0],
        )
    )
    ser = SerialEnv(16, lambda: GymEnv("Taxi-v4", categorical_action_encoding=True))
    rows.append(
        (
            "env: torchrl SerialEnv of 16 GymEnv",
            timed(lambda: ser.rollout(50, break_when_any_done=False).numel(), secs)[0],
        )
    )
    tab = make_gym_env("Taxi-v4", 16, backend="tabular")
    rows.append(
        (
            "env: TabularEnv (EnvBase), 16 envs",
            timed(lambda: tab.rollout(50, break_when_any_done=False).numel(), secs)[0],
        )
    )
    model = TabularModel.from_gym("Taxi-v4")
    s = torch.zeros(256, 16, dtype=torch.long)

    def raw_steps():
        nonlocal s
        for _ in range(100):
            a = torch.randint(6, s.shape)
            s = model.next_state[s, a, 0]
        return 100 * s.numel()

    rows.append(("env: batched table lookups, 256x16 envs (fast path)", timed(raw_steps, secs)[0]))

    # --- training -----------------------------------------------------------------------
    # each run writes into a folder of its own in a fresh scratch folder, removed at the end (a run
    # refuses a non-empty out_dir): runs of this script, one after another or side by side, never meet
    with tempfile.TemporaryDirectory(prefix="taxi_bench_") as root:
        t0 = time.perf_counter()
        train_gym(cfg(f"{root}/gym", env={"backend": "gym"}))
        rows.append(("train: 1 seed, TorchRL trainer, GymEnv backend", frames / (time.perf_counter() - t0)))
        t0 = time.perf_counter()
        train_gym(cfg(f"{root}/tabular"))
        rows.append(("train: 1 seed, TorchRL trainer, TabularEnv backend", frames / (time.perf_counter() - t0)))
        t0 = time.perf_counter()
        train_taxi_batched([cfg(f"{root}/batched_{i}", seed=i) for i in range(args.seeds)], write_outputs=False)
        rows.append(
            (f"train: {args.seeds} seeds batched (fast path)", args.seeds * frames / (time.perf_counter() - t0))
        )

    width = max(len(r[0]) for r in rows)
    print(f"\n{'measurement':<{width}}  {'per second':>14}")
    for name, v in rows:
        unit = "steps/s" if name.startswith("env") else "frames/s"
        print(f"{name:<{width}}  {v:>12,.0f} {unit}")
    r = dict(rows)
    print("\nratios")
    print(
        f"  TabularEnv / GymEnv (1 env)              {r['env: TabularEnv (EnvBase), 16 envs'] / r['env: torchrl GymEnv, 1 env, rollout']:8.1f}x"
    )
    print(
        f"  table lookups / SerialEnv(16 GymEnv)     {r['env: batched table lookups, 256x16 envs (fast path)'] / r['env: torchrl SerialEnv of 16 GymEnv']:8.1f}x"
    )
    one = r["train: 1 seed, TorchRL trainer, GymEnv backend"]
    print(
        f"  1 seed: TabularEnv / GymEnv backend      {r['train: 1 seed, TorchRL trainer, TabularEnv backend'] / one:8.1f}x"
    )
    print(
        f"  {args.seeds} seeds batched / 1 seed GymEnv       {r[f'train: {args.seeds} seeds batched (fast path)'] / one:8.1f}x"
    )
    print(
        f"  {args.seeds} seeds batched / 1 seed TabularEnv   "
        f"{r[f'train: {args.seeds} seeds batched (fast path)'] / r['train: 1 seed, TorchRL trainer, TabularEnv backend']:8.1f}x"
    )
    print(f"(torch threads: {torch.get_num_threads()}, frames per training measurement: {frames})")


if __name__ == "__main__":
    main()
