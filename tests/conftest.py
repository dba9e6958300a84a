import logging

import pytest
import torch

logging.getLogger("torchrl").setLevel(logging.WARNING)
# the test process is the owner of its settings (library calls no longer set them): one torch
# thread, as the recipes' defaults for these tiny networks and as the library used to set it
torch.set_num_threads(1)


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
