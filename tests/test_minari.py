"""State-only demos from a local Minari dataset (built here; nothing is downloaded)."""

import gymnasium as gym
import numpy as np
import pytest
import torch

minari = pytest.importorskip("minari")
pytest.importorskip("h5py")

from minari.data_collector import EpisodeBuffer  # noqa: E402

from torchrl_hybrid.data import EXPERT_ACTION_KEY  # noqa: E402
from torchrl_hybrid.data.minari import load_minari_demos  # noqa: E402
from torchrl_hybrid.envs import TabularModel  # noqa: E402
from torchrl_hybrid.experts import optimal_policy  # noqa: E402
from torchrl_hybrid.families.gym import config_from_dict, train_gym  # noqa: E402


def _record(env_id: str, dataset_id: str, policy, episodes: int, max_steps: int):
    """A Minari dataset of ``episodes`` episodes of ``policy(obs)`` in the cache
    MINARI_DATASETS_PATH points at; returns the episodes' (states, actions)."""
    env = gym.make(env_id, max_episode_steps=max_steps)
    buffers, recorded = [], []
    for ep in range(episodes):
        o, _ = env.reset(seed=ep)
        obs, acts, rews, terms, truncs = [o], [], [], [], []
        done = False
        while not done:
            a = policy(o)
            o, r, t, tr, _ = env.step(a)
            obs.append(o), acts.append(a), rews.append(r), terms.append(t), truncs.append(tr)
            done = t or tr
        buffers.append(
            EpisodeBuffer(
                id=ep,
                seed=ep,
                observations=np.stack(obs),
                actions=np.array(acts),
                rewards=np.array(rews),
                terminations=np.array(terms),
                truncations=np.array(truncs),
                infos={},
            )
        )
        recorded.append((np.stack(obs), np.array(acts)))
    minari.create_dataset_from_buffers(dataset_id, buffers, env=env, algorithm_name="test")
    env.close()
    return recorded


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    return tmp_path / "minari"


def _taxi_expert():
    model = TabularModel.from_gym("Taxi-v4")
    policy, _ = optimal_policy(model, 0.99)
    return lambda s: int(policy[int(s)])


def test_minari_episodes_become_state_only_pairs(cache):
    rng = np.random.default_rng(0)
    recorded = _record("CartPole-v1", "cartpole/random-v0", lambda o: int(rng.integers(2)), 3, 500)
    demos, meta = load_minari_demos("cartpole/random-v0", obs_shape=(4,), obs_dtype=torch.float32)
    assert EXPERT_ACTION_KEY not in demos.keys() and "action" not in demos.keys()  # dropped on load
    assert meta["env_id"] == "CartPole-v1" and meta["total_episodes"] == 3
    assert demos.batch_size.numel() == sum(len(a) for _, a in recorded)
    for i, (states, _) in enumerate(recorded):  # each episode's consecutive states, in order
        ep = demos[demos["trajectory"] == i]
        assert torch.equal(ep["step"], torch.arange(len(states) - 1))
        np.testing.assert_allclose(ep["observation"].numpy(), states[:-1])
        np.testing.assert_allclose(ep["next", "observation"].numpy(), states[1:])
    kept, _ = load_minari_demos("cartpole/random-v0", keep_actions=True)  # for diagnostics only
    assert torch.equal(kept[EXPERT_ACTION_KEY], torch.as_tensor(np.concatenate([a for _, a in recorded])))
    with pytest.raises(ValueError, match="observation shape"):
        load_minari_demos("cartpole/random-v0", obs_shape=(8,))


def test_a_missing_dataset_names_the_cache_and_downloads_nothing(cache):
    with pytest.raises(FileNotFoundError, match=r"no such dataset in the local Minari cache .*nothing is downloaded"):
        load_minari_demos("cartpole/nope-v0")


def test_the_taxi_agent_learns_from_a_minari_dataset(cache, tmp_path):
    _record("Taxi-v4", "taxi/expert-v0", _taxi_expert(), 20, 50)
    cfg = config_from_dict(
        {
            "total_frames": 640,
            "out_dir": str(tmp_path / "run"),
            "demo": {"minari": "taxi/expert-v0"},
            "logger": {"log_every_frames": 320, "eval_episodes": 8, "final_eval_episodes": 8, "progress_bar": False},
        }
    )
    s = train_gym(cfg)
    assert s["frames"] == 640 and s["idm_accuracy_expert"] is None  # no true actions: nothing to score against
    # demos recorded on another env are refused, and so are two demo sources at once
    _record("CliffWalking-v1", "cliff/random-v0", lambda s: 0, 1, 20)
    with pytest.raises(ValueError, match="demos are for CliffWalking-v1, this run plays Taxi-v4|states outside"):
        train_gym(
            config_from_dict(
                {"out_dir": str(tmp_path / "x"), "total_frames": 640, "demo": {"minari": "cliff/random-v0"}}
            )
        )
    with pytest.raises(ValueError, match="choose one demo source"):
        train_gym(
            config_from_dict(
                {
                    "out_dir": str(tmp_path / "y"),
                    "total_frames": 640,
                    "demo": {"minari": "taxi/expert-v0", "path": str(tmp_path)},
                }
            )
        )


def test_cartpole_hybrid_from_a_minari_dataset(cache, tmp_path):
    _record("CartPole-v1", "cartpole/random-v0", lambda o: int(o[2] > 0), 4, 500)  # a simple pole-following rule
    cfg = config_from_dict(
        {
            "total_frames": 800,
            "out_dir": str(tmp_path / "run"),
            "d_state": 16,
            "d": 16,
            "env": {"env_id": "CartPole-v1", "max_episode_steps": 500},
            "demo": {"minari": "cartpole/random-v0", "rho": "uniform"},
            "loss": {"n_steps": 5},
            "logger": {"log_every_frames": 400, "eval_episodes": 2, "final_eval_episodes": 2, "progress_bar": False},
        }
    )
    s = train_gym(cfg)
    assert s["frames"] == 800 and s["optimal_return"] is None  # no expert policy to evaluate
