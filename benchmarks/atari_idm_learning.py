"""Does the inverse model learn on Atari? Loss and accuracy vs frames, IDM alone.

    python benchmarks/atari_idm_learning.py --game Breakout --frames 128000

Collects transitions with the untrained (near-uniform) policy of 16 envs (``--num-envs``) and
trains only the inverse model and the shared CNN on them, 80 transitions per
update (RMSprop 7e-4, clip 0.5, as the Atari runs), for: the dual model with the
paper's L1 embedding terms (``embedding_coeff`` 0.1, as the authors' Taxi code),
the dual model without them, and the MLP model. Prints the mean inverse loss and
accuracy on the training transitions over windows of 100 updates (and the
updates after the last full window); chance level is ln(n_actions) and
1/n_actions. The runs are independent processes, ``--workers`` (2) at a time.
A smoke run: ``--frames 640 --workers 1 --num-envs 2``.
"""

from __future__ import annotations

import argparse
import math
import multiprocessing as mp
import time


def train(args: tuple) -> tuple[str, list[tuple[int, float, float]]]:
    game, model, emb, frames, seed, *rest = args
    num_envs = rest[0] if rest else 16
    import torch
    from torchrl.collectors import Collector

    from torchrl_hybrid.envs.atari import AtariEnv
    from torchrl_hybrid.modules import DualInverseDynamics, MLPInverseDynamics, make_atari_actor_critic
    from torchrl_hybrid.objectives import DualInverseDynamicsLoss, InverseDynamicsLoss

    torch.manual_seed(seed)
    torch.set_num_threads(1)
    env = AtariEnv(game, num_envs, num_threads=1, seed=seed)
    _, _, enc, policy = make_atari_actor_critic(env.n_actions)
    if model == "mlp":
        loss = InverseDynamicsLoss(MLPInverseDynamics(enc, env.n_actions), action_coeff=1.0)
    else:
        loss = DualInverseDynamicsLoss(
            DualInverseDynamics(enc, env.n_actions, rank=8), action_coeff=1.0, embedding_coeff=emb
        )
    opt = torch.optim.RMSprop(loss.parameters(), lr=7e-4, eps=1e-5, alpha=0.99)
    steps = frames // 4
    collector = Collector(env, policy, frames_per_batch=80, total_frames=steps, auto_register_policy_transforms=False)
    rows, li, acc = [], [], []
    for i, batch in enumerate(collector):
        out = loss(batch)
        sum(v for k, v in out.items() if k.startswith("loss_")).backward()
        torch.nn.utils.clip_grad_norm_(loss.parameters(), 0.5)
        opt.step()
        opt.zero_grad()
        li.append(float(out["loss_inverse"].detach()))
        with torch.no_grad():
            logits = loss.inverse_model.action_logits(batch["observation"], batch["next", "observation"])
            acc.append(float((logits.argmax(-1) == batch["action"]).float().mean()))
        if (i + 1) % 100 == 0:
            rows.append(((i + 1) * 320, sum(li[-100:]) / 100, sum(acc[-100:]) / 100))
    if len(li) % 100:  # the updates after the last full window
        k = len(li) % 100
        rows.append((len(li) * 320, sum(li[-k:]) / k, sum(acc[-k:]) / k))
    collector.shutdown()
    name = "mlp" if model == "mlp" else f"dual, embedding_coeff {emb:g}"
    return name, rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--game", default="Breakout")
    p.add_argument("--frames", type=int, default=128_000, help="game frames per run (4 per agent step)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=2, help="runs trained at a time (one process each)")
    p.add_argument("--num-envs", type=int, default=16, help="envs collecting the 80 transitions of an update")
    a = p.parse_args()
    if a.frames < 320:
        p.error(f"--frames must be >= 320 (one update: 80 agent steps of 4 frames), got {a.frames}")
    if a.workers < 1:
        p.error(f"--workers must be >= 1, got {a.workers}")
    if a.num_envs < 1 or 80 % a.num_envs:
        p.error(f"--num-envs must divide the 80 transitions of an update, got {a.num_envs}")
    from torchrl_hybrid.envs.atari import AtariEnv

    try:  # the game's action count (chance level), and a game ale-py has
        env = AtariEnv(a.game, 1)
    except Exception as err:
        p.error(f"--game {a.game}: {err}")
    n = env.n_actions
    env.close()
    jobs = [
        (a.game, "dual", 0.1, a.frames, a.seed, a.num_envs),
        (a.game, "dual", 0.0, a.frames, a.seed, a.num_envs),
        (a.game, "mlp", 0.0, a.frames, a.seed, a.num_envs),
    ]
    t0 = time.perf_counter()
    with mp.get_context("spawn").Pool(a.workers) as pool:
        results = pool.map(train, jobs)
    print(
        f"\n{a.game}: inverse model trained alone on the untrained policy's transitions "
        f"(chance: loss {math.log(n):.3f}, accuracy {1 / n:.3f}); {time.perf_counter() - t0:.0f} s"
    )
    for name, rows in results:
        print(f"  {name}")
        for frames, loss, acc in rows:
            print(f"    {frames:>8,} frames  loss {loss:.3f}  accuracy {acc:.3f}")


if __name__ == "__main__":
    main()
