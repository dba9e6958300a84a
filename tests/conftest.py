import logging

import pytest
import torch

logging.getLogger("torchrl").setLevel(logging.WARNING)


@pytest.fixture(autouse=True)
def _seed():
    torch.manual_seed(0)


@pytest.fixture(scope="session")
def taxi():
    from torchrl_hybrid.envs import TabularModel
    from torchrl_hybrid.experts import optimal_policy

    model = TabularModel.from_gym("Taxi-v4")
    policy, optimal = optimal_policy(model)
    return model, policy, optimal
