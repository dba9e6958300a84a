import logging
import os

import pytest
import torch

from torchrl_hybrid.testing import register_stand_in

logging.getLogger("torchrl").setLevel(logging.WARNING)

if os.environ.get("PYTEST_XDIST_WORKER"):
    # `make test` runs the suite in parallel worker processes (pytest-xdist), one per core:
    # one torch thread each keeps them from oversubscribing the cores
    torch.set_num_threads(1)

# the device-rule stand-in (tests/test_device_rules.py) must exist before the first backward pass
# of the process: autograd sizes its per-device queues then
register_stand_in()

#: where the tests that build a run put its networks: cpu in CI; `make test-cuda` runs the suite with cuda
TEST_DEVICE = os.environ.get("TORCHRL_HYBRID_TEST_DEVICE", "cpu")
if TEST_DEVICE.startswith("cuda") and not torch.cuda.is_available():
    raise RuntimeError(f"TORCHRL_HYBRID_TEST_DEVICE={TEST_DEVICE} but PyTorch sees no CUDA GPU")


@pytest.fixture
def device() -> str:
    """The device of every test that builds a run: ``cpu`` in CI, ``cuda`` under
    ``make test-cuda`` (TORCHRL_HYBRID_TEST_DEVICE=cuda)."""
    return TEST_DEVICE


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
