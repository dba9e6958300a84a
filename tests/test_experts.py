import torch

from torchrl_hybrid.experts import expected_return, value_iteration


def test_taxi_expert_is_optimal(taxi):
    model, policy, optimal = taxi
    assert abs(expected_return(model, policy) - 7.93) < 1e-6
    V, Q = value_iteration(model)
    # the expert's action is optimal in every state and Bellman's equation holds
    assert torch.allclose(Q.gather(1, policy[:, None]).squeeze(1), V)
    assert optimal[torch.arange(500), policy].all()
    # a worse policy scores lower
    assert expected_return(model, (policy + 1) % 6) < 7.0


def test_discounted_expert_reaches_the_goal_where_the_undiscounted_one_loops():
    from torchrl_hybrid.envs import TabularModel
    from torchrl_hybrid.experts import episode_ends, optimal_policy

    lake = TabularModel.from_gym("FrozenLake-v1", map_name="8x8", is_slippery=False)
    loops, _ = optimal_policy(lake, gamma=1.0)  # every action keeping the goal reachable ties; LEFT (0) wins
    assert not episode_ends(lake, loops, 100).any() and expected_return(lake, loops, 100) == 0.0
    expert, _ = optimal_policy(lake)  # gamma 0.99: the shortest way, 14 steps
    assert episode_ends(lake, expert, 100).all() and expected_return(lake, expert, 100) == 1.0
    assert not episode_ends(lake, expert, 13).any() and episode_ends(lake, expert, 14).all()
