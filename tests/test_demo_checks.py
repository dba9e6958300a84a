"""Demos checked against the env as far as it allows, when a run loads them (demo.path):
true actions against Taxi's table P, trajectories that chain, vector observations inside
the observation space, Atari demos with their metadata.json. Each corrupted dataset is made
with the project's own recording and save functions, then damaged in one way."""

import pytest
import torch
from conftest import TEST_DEVICE
from tensordict import TensorDict
from tensordict.nn import TensorDictModule

from torchrl_hybrid.data import pairs_from_trajectories, save_demos, tabular_trajectories
from torchrl_hybrid.data.checks import UNBOUNDED_LIMIT
from torchrl_hybrid.experts import record_episodes
from torchrl_hybrid.experts.scripted import CallablePolicy
from torchrl_hybrid.families.gym import config_from_dict, make_gym_demos, make_taxi_demos, train_gym

CARTPOLE = {
    "env.env_id": "CartPole-v1",
    "env.max_episode_steps": 200,
    "demo.rho": "uniform",
    "demo.form": "trajectories",
    "loss.n_steps": 5,
    "d_state": 16,
    "d": 16,
    "encoder.hidden": 16,
}


def tiny(tmp_path, **kw):
    d = {
        "total_frames": 640,
        "out_dir": str(tmp_path / "run"),
        "device": TEST_DEVICE,
        "logger": {
            "log_every_frames": 320,
            "eval_episodes": 8,
            "final_eval_episodes": 8,
            "progress_bar": False,
            "backend": "csv",
        },
    }
    for k, v in kw.items():
        if "." in k:
            g, kk = k.split(".")
            d.setdefault(g, {})[kk] = v
        else:
            d[k] = v
    return config_from_dict(d)


@pytest.fixture(scope="module")
def cartpole_demos():
    """Four CartPole episodes recorded as the pipeline records them (an expert that always
    pushes left: its episodes end in about ten steps)."""
    policy = TensorDictModule(
        CallablePolicy(lambda obs: torch.zeros(obs.shape[:-1], dtype=torch.long)),
        in_keys=["observation"],
        out_keys=["action"],
    )
    demos, _ = record_episodes("CartPole-v1", policy, 4, 200, seed=0, num_envs=4)
    return demos


def test_taxi_demos_with_random_true_actions_are_refused_by_il(tmp_path, taxi):
    model, policy, _ = taxi
    demos = tabular_trajectories(model, policy, 5, 50, torch.Generator().manual_seed(0))
    demos["expert_action"] = torch.randint(model.n_actions, demos.shape, generator=torch.Generator().manual_seed(1))
    save_demos(demos, tmp_path / "random_actions", {"env_id": "Taxi-v4"})
    with pytest.raises(
        ValueError,
        match=r"random_actions: \d+ of \d+ pairs \(s, a, s'\) are not transitions of "
        r"Taxi-v4.*first: pair \d+.*re-record them",
    ):
        train_gym(tiny(tmp_path, variant="il", **{"demo.path": str(tmp_path / "random_actions")}))


def test_cartpole_demos_with_shuffled_next_states_are_refused(tmp_path, cartpole_demos):
    demos = cartpole_demos.clone()
    demos["next", "observation"] = demos["next", "observation"][torch.randperm(len(demos))]
    save_demos(demos, tmp_path / "shuffled", {"env_id": "CartPole-v1"})
    with pytest.raises(
        ValueError,
        match=r"shuffled: \d+ of \d+ consecutive pairs within a trajectory do not chain "
        r".*first: pair \d+.*re-record them",
    ):
        train_gym(tiny(tmp_path, **CARTPOLE, **{"demo.path": str(tmp_path / "shuffled")}))


def test_cartpole_demos_far_outside_the_observation_space_are_refused(tmp_path, cartpole_demos):
    demos = cartpole_demos.clone()
    demos["observation"] *= 1e6
    demos["next", "observation"] *= 1e6
    save_demos(demos, tmp_path / "scaled", {"env_id": "CartPole-v1"})
    n = len(demos)
    with pytest.raises(
        ValueError,
        match=rf"scaled: {n} of {n} pairs have observations outside the observation "
        r"space of CartPole-v1 \(first: pair 0.*re-record them",
    ):
        train_gym(tiny(tmp_path, **CARTPOLE, **{"demo.path": str(tmp_path / "scaled")}))
    # a dimension without a bound (the cart's velocity) takes up to UNBOUNDED_LIMIT, no more
    fast = cartpole_demos.clone()
    fast["observation"][0, 1] = 2 * UNBOUNDED_LIMIT
    save_demos(fast, tmp_path / "fast", {"env_id": "CartPole-v1"})
    with pytest.raises(ValueError, match=rf"fast: 1 of {n} pairs .*'observation'\[1\] = 20000"):
        make_gym_demos(tiny(tmp_path, **CARTPOLE, **{"demo.path": str(tmp_path / "fast")}), None, 4)


def test_atari_demos_without_metadata_say_where_and_how_to_record(tmp_path):
    pytest.importorskip("ale_py")
    from torchrl_hybrid.families.atari import atari_config, train_atari

    frames = torch.randint(0, 255, (2, 7, 84, 84), dtype=torch.uint8, generator=torch.Generator().manual_seed(0))
    stacks = [torch.stack([f[t : t + 4] for t in range(4)]) for f in frames]  # 2 trajectories of 4 stacked states
    save_demos(pairs_from_trajectories(stacks), tmp_path / "demos")
    (tmp_path / "demos" / "metadata.json").unlink()
    cfg = atari_config(
        {
            "env": {"num_envs": 2, "num_threads": 1},
            "out_dir": str(tmp_path / "run"),
            "device": TEST_DEVICE,
            "total_frames": 256,
            "loss": {"n_steps": 4, "bc_start_frames": 64},
            "logger": {"progress_bar": False, "log_every_frames": 128, "checkpoint": False},
            "demo": {"path": str(tmp_path / "demos")},
        }
    )
    with pytest.raises(
        FileNotFoundError,
        match=r"demos: no metadata.json \(looked for .*demos/metadata.json\).*"
        r"recipes/atari_demos.py expert=<model.pt> out=<folder>",
    ):
        train_atari(cfg)


def test_clean_recordings_pass_every_check(tmp_path, taxi, cartpole_demos):
    # CartPole: recorded episodes, saved and loaded as a run loads them
    save_demos(cartpole_demos, tmp_path / "cartpole", {"env_id": "CartPole-v1"})
    loaded = make_gym_demos(tiny(tmp_path, **CARTPOLE, **{"demo.path": str(tmp_path / "cartpole")}), None, 4)
    assert torch.equal(loaded["next", "observation"], cartpole_demos["next", "observation"])
    # Taxi: the expert's trajectories with noise (dropped states, redrawn pairs) written by a run, then loaded
    model, _, _ = taxi
    noisy = {"demo.form": "trajectories", "demo.num_trajectories": 5, "demo.eta": 0.2, "demo.epsilon": 0.2}
    written, _ = make_taxi_demos(
        tiny(tmp_path, **noisy, **{"demo.save_path": str(tmp_path / "taxi")}), model, torch.Generator().manual_seed(0)
    )
    assert bool(written["corrupted"].any())
    loaded, _ = make_taxi_demos(
        tiny(tmp_path, **{"demo.path": str(tmp_path / "taxi")}), model, torch.Generator().manual_seed(0)
    )
    assert torch.equal(loaded["expert_action"], written["expert_action"])
    # no trajectory index (one pair per state, or a foreign dataset): nothing to chain
    pairs = TensorDict({"observation": torch.zeros(3, 4), ("next", "observation"): torch.full((3, 4), 0.1)}, [3])
    save_demos(pairs, tmp_path / "pairs", {"env_id": "CartPole-v1"})
    make_gym_demos(tiny(tmp_path, **CARTPOLE, **{"demo.path": str(tmp_path / "pairs")}), None, 4)
