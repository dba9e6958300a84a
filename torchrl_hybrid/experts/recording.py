"""Demo recording: an expert plays, its state sequences are kept (the actions only under
``EXPERT_ACTION_KEY``, for diagnostics). :func:`record_episodes` for gymnasium envs,
:func:`record_demos` for Atari (a memory-mapped dataset with metadata)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type
from tqdm import tqdm

from torchrl_hybrid.data import pairs_from_trajectories, save_demos
from torchrl_hybrid.envs import make_gym_env
from torchrl_hybrid.envs.atari import AtariEnv
from torchrl_hybrid.experts.checkpoints import load_expert
from torchrl_hybrid.utils.device import module_device

__all__ = ["record_episodes", "record_demos"]


@torch.no_grad()
def record_episodes(
    env_id: str,
    policy,
    num_episodes: int,
    max_steps: int,
    *,
    seed: int = 0,
    env_kwargs: dict | None = None,
    deterministic: bool = True,
    num_envs: int = 16,
):
    """Plays ``num_episodes`` whole episodes of ``policy`` and returns them as expert
    pairs (:func:`~torchrl_hybrid.data.pairs_from_trajectories`: ``step`` and
    ``trajectory`` indices, the true actions under ``expert_action``) and the
    ``[num_episodes]`` episode returns."""
    states, actions, returns = [], [], []
    etype = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    round_ = 0
    while len(states) < num_episodes:
        n = min(num_envs, num_episodes - len(states))
        env = make_gym_env(env_id, n, max_episode_steps=max_steps, seed=seed + 1000 * round_, env_kwargs=env_kwargs)
        with set_exploration_type(etype):
            td = env.rollout(max_steps, policy, break_when_any_done=False)
        env.close()
        done = td.get(("next", "done")).squeeze(-1)
        if not done.any(-1).all():
            raise RuntimeError(f"an expert episode did not end within {max_steps} steps; raise env.max_episode_steps")
        for i in range(n):
            end = int(done[i].nonzero()[0])  # the first episode of env i: steps 0..end
            states.append(torch.cat([td["observation"][i, : end + 1], td["next", "observation"][i, end : end + 1]]))
            actions.append(td["action"][i, : end + 1])
            returns.append(float(td["next", "reward"][i, : end + 1].sum()))
        round_ += 1
    return pairs_from_trajectories(states, actions), torch.tensor(returns)


@torch.no_grad()
def record_demos(
    expert_path: str | Path,
    out_path: str | Path,
    *,
    num_trajectories: int = 100,
    num_envs: int = 16,
    seed: int = 0,
    deterministic: bool = False,
    max_steps: int = 27_000,
    cut: str = "auto",
    progress: bool = True,
    device: str | torch.device = "auto",
    overwrite: bool = False,
) -> dict[str, Any]:
    """Plays the expert and saves ``num_trajectories`` state-only trajectories as a
    memory-mapped dataset of expert pairs with metadata. True actions go only under
    ``EXPERT_ACTION_KEY``.

    ``cut`` says where a trajectory ends (always at the episode's end or after
    ``max_steps`` at the latest): ``"life"`` at the first life lost (the paper);
    ``"point"`` at the first negative reward (a point lost: the analogue of a life in
    games without lives such as Pong, whose whole episodes run to thousands of steps);
    ``"episode"`` never earlier; ``"auto"`` = ``"life"`` when the game has lives,
    else ``"point"``.
    """
    if cut not in ("auto", "life", "point", "episode"):
        raise ValueError(f"cut={cut!r}: choose one of 'auto', 'life', 'point', 'episode'")
    if num_trajectories < 1 or max_steps < 1:
        raise ValueError(f"num_trajectories and max_steps must be >= 1, got {num_trajectories}, {max_steps}")
    out = Path(out_path)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not overwrite:  # before minutes of play
        raise ValueError(
            f"{out} already exists and is not empty; pass overwrite=true to replace it or choose another folder"
        )
    actor, ckpt = load_expert(expert_path, device)
    device = module_device(actor)
    torch.manual_seed(seed)  # the expert's sampled actions: the same seed records the same demos
    game = ckpt["config"]["env"]["game"]
    pre = ckpt["preprocessing"]
    env = AtariEnv(
        game,
        num_envs,
        seed=seed,
        num_threads=ckpt["config"]["env"]["num_threads"],
        noop_max=pre["noop_max"],
        max_episode_frames=pre["max_episode_frames"],
    )
    env.check_policy(actor)
    td = env.reset()
    # per env: the trajectory being recorded, or None while waiting for the episode to end
    states: list[list[torch.Tensor] | None] = [[td["observation"][i].clone()] for i in range(num_envs)]
    actions: list[list[int]] = [[] for _ in range(num_envs)]
    scores = [0.0] * num_envs
    lives0 = td["lives"].squeeze(-1).clone()
    if cut == "auto":
        cut = "life" if bool((lives0 > 0).all()) else "point"
    trajs, acts, returns, ends = [], [], [], []
    etype = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    bar = tqdm(total=num_trajectories, desc=f"{game} demos", disable=not progress)
    while len(trajs) < num_trajectories:
        with set_exploration_type(etype):
            td = actor(td.to(device)).to("cpu")
        td, root = env.step_and_maybe_reset(td)
        nxt = td["next"]
        done = nxt["done"].squeeze(-1)
        lives = nxt["lives"].squeeze(-1)
        for i in range(num_envs):
            if states[i] is not None:
                states[i].append(nxt["observation"][i].clone())
                actions[i].append(int(td["action"][i]))
                scores[i] += float(nxt["score"][i])
                end = (
                    "life"
                    if cut == "life" and bool(lives[i] < lives0[i])
                    else "point"
                    if cut == "point" and float(nxt["score"][i]) < 0
                    else "episode"
                    if bool(done[i])
                    else "max_steps"
                    if len(actions[i]) >= max_steps
                    else None
                )
                if end is not None and len(trajs) < num_trajectories:
                    ends.append(end)
                    trajs.append(torch.stack(states[i]))
                    acts.append(torch.tensor(actions[i]))
                    returns.append(scores[i])
                    bar.update(1)
                    states[i] = None
            if bool(done[i]):  # a new episode starts: record it from its first state
                states[i], actions[i], scores[i] = [root["observation"][i].clone()], [], 0.0
                lives0[i] = root["lives"][i, 0]
        td = root
    bar.close()
    env.close()
    demos = pairs_from_trajectories(trajs, acts)
    lengths = [len(a) for a in acts]
    meta = {
        "game": game,
        "preprocessing": pre,
        "expert_checkpoint": str(Path(expert_path).resolve()),
        "expert_frames": ckpt.get("total_frames_seen", ckpt["config"]["total_frames"]),
        "num_trajectories": len(trajs),
        "returns": returns,
        "lengths": lengths,
        "ends": ends,
        "deterministic": deterministic,
        "seed": seed,
        "cut": {"life": "first life lost", "point": "first point lost (negative reward)", "episode": "episode end"}[cut]
        + f", episode end or {max_steps} steps",
    }
    save_demos(demos, out_path, meta, overwrite=overwrite)
    return meta
