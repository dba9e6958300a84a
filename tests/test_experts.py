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
