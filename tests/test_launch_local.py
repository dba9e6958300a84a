"""The local launcher (worker processes, no Ray): a worker killed in the middle of a job
stops the study with an error that says how to continue, instead of a wait forever."""

import os
import signal

import pytest

from torchrl_hybrid.utils.launch import run_jobs


def _die_on_two(x):
    import time

    if x == 2:
        os.kill(os.getpid(), signal.SIGKILL)  # what the kernel's OOM killer does
    time.sleep(0.1)
    return x * x


def _square(x):
    return x * x


def _raise(x):
    raise ValueError(f"bad job {x}")


@pytest.fixture
def alarm():
    """Fails the test (instead of hanging the suite) if run_jobs waits for a dead worker."""

    def boom(*_):
        raise TimeoutError("run_jobs waited 60 s for a killed worker")

    old = signal.signal(signal.SIGALRM, boom)
    signal.alarm(60)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


def test_local_workers_give_every_result_once():
    assert sorted(run_jobs(_square, list(range(5)), launcher="local", workers=2)) == [0, 1, 4, 9, 16]
    assert sorted(run_jobs(_square, list(range(5)), launcher="local", workers=2, fresh_process=True)) == [
        0,
        1,
        4,
        9,
        16,
    ]


def test_a_job_error_reaches_the_caller():
    with pytest.raises(ValueError, match="bad job"):
        list(run_jobs(_raise, [1, 2], launcher="local", workers=2))


def test_a_killed_worker_stops_the_study_with_how_to_continue(alarm):
    with pytest.raises(RuntimeError, match="worker process died.*Run the same command again"):
        list(run_jobs(_die_on_two, [0, 1, 2, 3], launcher="local", workers=2))


def test_a_ray_cluster_that_fails_says_to_run_the_same_command_again(monkeypatch):
    """The raylet of this node dying surfaces as LocalRayletDiedError from ray.wait; the study
    stops with the documented way on, not with Ray's error (a stand-in Ray: no cluster needed)."""
    import types

    import torchrl_hybrid.utils.launch as launch

    class LocalRayletDiedError(Exception):
        pass

    class RaySystemError(Exception):
        pass

    cancelled, shut = [], []

    def wait(refs, num_returns):
        raise LocalRayletDiedError("the raylet of this node died")

    def cancel(ref, force):
        cancelled.append(ref)
        raise RaySystemError("no cluster to cancel on")

    fake = types.SimpleNamespace(
        exceptions=types.SimpleNamespace(
            LocalRayletDiedError=LocalRayletDiedError,
            RaySystemError=RaySystemError,
            WorkerCrashedError=type("W", (Exception,), {}),
            NodeDiedError=type("N", (Exception,), {}),
            OutOfMemoryError=type("O", (Exception,), {}),
        ),
        remote=lambda **kw: lambda f: types.SimpleNamespace(remote=lambda fn, job: ("ref", job)),
        wait=wait,
        cancel=cancel,
        shutdown=lambda: shut.append(True),
    )
    monkeypatch.setattr(launch, "_ray", lambda: fake)
    monkeypatch.setattr(launch, "init_ray", lambda address, num_cpus: True)
    with pytest.raises(
        RuntimeError,
        match=r"the Ray cluster failed \(LocalRayletDiedError: the raylet of this node "
        r"died\); the study stops here. Run the same command again to continue",
    ):
        list(run_jobs(_square, [1, 2], launcher="ray"))
    assert cancelled and shut == [True]
