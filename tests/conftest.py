import logging
import os

import pytest
import torch

logging.getLogger("torchrl").setLevel(logging.WARNING)

if os.environ.get("PYTEST_XDIST_WORKER"):
    # `make test` runs the suite in parallel worker processes (pytest-xdist), one per core:
    # one torch thread each keeps them from oversubscribing the cores
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
