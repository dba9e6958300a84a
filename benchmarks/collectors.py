"""Collection throughput of the gymnasium pipeline's collector kinds, side by side in one
run: TorchRL's Collector in this process, MultiSyncCollector and RayCollector with 1, 2
and 4 workers. Each batch is env.num_envs x n_steps transitions of the tabular (Taxi) or
MLP (CartPole) policy, and the workers get the policy's weights after every batch, as in
training (the learner's own time is not included).

    python benchmarks/collectors.py                         # Taxi and CartPole, 16 envs
    python benchmarks/collectors.py --envs CartPole-v1 --workers 1 2 --batches 100
    python benchmarks/collectors.py --envs Taxi-v4 --workers 1 --batches 2 --num-envs 2 --no-ray   # a smoke run
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import time

import torch

logging.getLogger("torchrl").setLevel(logging.WARNING)


def measure(env_id: str, kind: str, workers: int, batches: int, num_envs: int) -> float:
    from torchrl_hybrid.envs import make_gym_env, observation_kind
    from torchrl_hybrid.families.gym import config_from_dict, make_collector
    from torchrl_hybrid.modules import make_mlp_actor_critic, make_tabular_actor_critic

    obs, size, n_actions = observation_kind(env_id)
    n_steps = 2 if obs == "discrete" else 5
    cfg = config_from_dict(
        {
            "env": {"env_id": env_id, "num_envs": num_envs, "max_episode_steps": 50 if obs == "discrete" else 500},
            "loss": {"n_steps": n_steps},
            "total_frames": num_envs * n_steps * (batches + 5),
            "collector": {"kind": kind, "workers": workers},
        }
    )
    actor = (
        make_tabular_actor_critic(size, n_actions)[0]
        if obs == "discrete"
        else make_mlp_actor_critic(size, n_actions)[0]
    )
    env = make_gym_env(env_id, num_envs, max_episode_steps=cfg.env.max_episode_steps, seed=0)
    collector = make_collector(cfg, env, actor, torch.device("cpu"))
    frames, t0 = 0, None
    for i, batch in enumerate(collector):
        if i == 5:  # warm-up batches (process start, first weight transfer) are not timed
            t0 = time.perf_counter()
        elif i > 5:
            frames += batch.numel()
        collector.update_policy_weights_()
    rate = frames / (time.perf_counter() - t0)
    collector.shutdown()
    return rate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--envs", nargs="+", default=["Taxi-v4", "CartPole-v1"])
    ap.add_argument("--workers", nargs="+", type=int, default=[1, 2, 4])
    ap.add_argument("--batches", type=int, default=200)
    ap.add_argument("--num-envs", type=int, default=16)
    ap.add_argument("--no-ray", action="store_true", help="skip RayCollector")
    args = ap.parse_args()
    if args.batches < 2:  # the clock starts when a batch arrives: the first one after the warm-up is not counted
        ap.error(f"--batches must be >= 2 (the rate is taken over batches - 1), got {args.batches}")
    if args.num_envs < 1:
        ap.error(f"--num-envs must be >= 1, got {args.num_envs}")
    bad = [w for w in args.workers if w < 1 or args.num_envs % w]
    if bad:
        ap.error(f"--workers {bad}: each must be >= 1 and divide --num-envs {args.num_envs}")
    if not args.no_ray and importlib.util.find_spec("ray") is None:
        ap.error("RayCollector needs Ray (pip install 'ray>=2.9', or the project's [ray] extra); or pass --no-ray")
    from torchrl_hybrid.envs import observation_kind

    for env_id in args.envs:
        try:
            observation_kind(env_id)
        except Exception as err:  # an unknown id, a space this pipeline does not take
            ap.error(f"--envs {env_id}: {err}")
    torch.set_num_threads(1)
    kinds = ["multi_sync"] + ([] if args.no_ray else ["ray"])
    if not args.no_ray:
        from torchrl_hybrid.utils.launch import init_ray

        init_ray(num_cpus=max(args.workers))
    for env_id in args.envs:
        single = measure(env_id, "single", 1, args.batches, args.num_envs)
        print(f"{env_id:12s} single (this process)   {single:9.0f} frames/s   1.00x", flush=True)
        for kind in kinds:
            for w in args.workers:
                r = measure(env_id, kind, w, args.batches, args.num_envs)
                print(f"{env_id:12s} {kind:10s} {w} worker(s) {r:9.0f} frames/s   {r / single:.2f}x", flush=True)


if __name__ == "__main__":
    main()
