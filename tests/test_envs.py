import gymnasium as gym
import pytest
import torch
from torchrl.collectors import Collector

from torchrl_hybrid.envs import TabularEnv, TabularModel, make_gym_env


def test_tabular_model_matches_gymnasium_on_every_state_action(taxi):
    model, _, _ = taxi
    env = gym.make("Taxi-v4").unwrapped
    env.reset(seed=0)
    for s in range(500):
        for a in range(6):
            env.s = s
            s2, r, term, trunc, _ = env.step(a)
            assert model.next_state[s, a, 0] == s2
            assert model.reward[s, a, 0] == r
            assert bool(model.terminated[s, a, 0]) == term
    assert model.deterministic


def test_tabular_env_steps_like_the_table_and_truncates(taxi):
    model, _, _ = taxi
    env = TabularEnv(model, batch_size=(500,), max_episode_steps=3, seed=0)
    env.reset()
    for a in range(6):
        td = env.reset()
        env._state = torch.arange(500)  # put env i in state i
        td = env.step(td.set("action", torch.full((500,), a)))
        assert torch.equal(td["next", "observation"], model.next_state[:, a, 0])
        assert torch.equal(td["next", "reward"].squeeze(-1), model.reward[:, a, 0])
        assert torch.equal(td["next", "terminated"].squeeze(-1), model.terminated[:, a, 0])
    # time limit: an action that never terminates (move south) truncates at step 3
    env = TabularEnv(model, batch_size=(4,), max_episode_steps=3, seed=0)
    td = env.rollout(3, lambda td: td.set("action", torch.zeros(4, dtype=torch.long)), break_when_any_done=False)
    assert td["next", "truncated"].squeeze(-1).tolist() == [[False, False, True]] * 4
    assert not td["next", "terminated"].any()


def test_start_distribution_matches_gymnasium(taxi):
    model, _, _ = taxi
    isd = torch.as_tensor(gym.make("Taxi-v4").unwrapped.initial_state_distrib, dtype=torch.float32)
    assert torch.equal(model.initial_dist, isd)
    env = TabularEnv(model, batch_size=(20000,), seed=1)
    starts = env.reset()["observation"]
    assert (isd[starts] > 0).all()
    assert len(torch.unique(starts)) == 300  # every one of the 300 start states is drawn


def test_gym_and_tabular_backends_present_the_same_interface():
    tab = make_gym_env(num_envs=2, backend="tabular", seed=0)
    gy = make_gym_env(num_envs=2, backend="gym", seed=0)
    for env in (tab, gy):
        td = env.rollout(4, break_when_any_done=False)
        assert td["observation"].shape == (2, 4) and td["observation"].dtype == torch.long
        assert td["action"].shape == (2, 4)
        assert td["next", "episode_reward"].shape == (2, 4, 1)


def test_unknown_backend_and_env_without_table():
    with pytest.raises(ValueError, match="backend"):
        make_gym_env(backend="fast")
    with pytest.raises(ValueError, match="no transition table"):
        TabularModel.from_gym("CartPole-v1")


def test_collected_pairs_are_true_transitions_even_across_resets(taxi):
    """("next", "observation") is the real successor, never the reset state."""
    model, _, _ = taxi
    env = make_gym_env(num_envs=8, max_episode_steps=5, seed=0)
    collector = Collector(env, None, frames_per_batch=400, total_frames=400)
    batch = next(iter(collector))
    s, a, s2 = batch["observation"], batch["action"], batch["next", "observation"]
    assert batch["next", "done"].sum() > 50  # plenty of episode ends in the batch
    assert torch.equal(model.next_state[s, a, 0], s2)
