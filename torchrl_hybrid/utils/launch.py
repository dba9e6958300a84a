"""Where a study's runs execute: local worker processes (the default) or Ray tasks.

Every study (``taxi_sweep``, ``atari_compare``, ``recipes/compare.py``) hands its jobs to
:func:`run_jobs`, which yields each job's result as it finishes. With
``launcher="ray"`` each job is a Ray task: ``ray.init(address=...)`` joins an existing
cluster, no address starts a local one on this machine. A local worker process that
dies stops the study with an error that says how to continue. On Ray, a job whose worker process
dies (killed, out of memory, node lost) is started again by Ray up to
``max_retries`` times; the studies make that safe: results are keyed by run, finished
runs are kept and an interrupted run resumes from its checkpoint. When the retries run
out, the study stops with an error that says how to continue.
"""

from __future__ import annotations

import math
import multiprocessing as mp
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

__all__ = ["LAUNCHERS", "in_worker", "init_ray", "run_jobs"]

LAUNCHERS = ("local", "ray")

_IN_WORKER = False  # true in the processes run_jobs starts (local pool workers, Ray workers)


def _mark_worker() -> None:
    global _IN_WORKER
    _IN_WORKER = True


def in_worker() -> bool:
    """Whether this process is a worker that :func:`run_jobs` started (so a job may set
    process-wide settings such as torch's thread count), rather than the caller's own."""
    return _IN_WORKER


def _ray_job(fn: Callable[[Any], Any], job: Any) -> Any:
    _mark_worker()
    return fn(job)


def _ray():
    try:
        import ray
    except ImportError:
        raise ValueError("launcher=ray needs Ray: pip install -e '.[ray]' (or pip install ray)") from None
    return ray


def init_ray(address: str | None = None, num_cpus: int | None = None) -> bool:
    """Joins the Ray cluster at ``address``, or starts a local one with ``num_cpus`` CPUs on
    the loopback address, unless Ray is already initialised. Returns whether it started
    (or joined) here, i.e. whether the caller should shut it down.

    Ray runs its workers at niceness 15 by default, so that on a machine shared with other
    work they get the CPU last (measured: a Taxi sweep configuration took 55 s in a Ray task
    against 12 s in the driver while an Atari run trained beside it); the local cluster
    started here runs them at 0, as the local launcher's processes."""
    ray = _ray()
    if ray.is_initialized():
        return False
    if address is None:
        ray.init(
            num_cpus=num_cpus,
            include_dashboard=False,
            log_to_driver=False,
            _node_ip_address="127.0.0.1",
            _system_config={"worker_niceness": 0},
        )
    else:
        ray.init(address=address, log_to_driver=False)
    return True


def _run_local(
    fn: Callable[[Any], Any], jobs: Sequence[Any], workers: int, fresh_process: bool, poll: Callable[[], None] | None
) -> Iterator[Any]:
    """``workers`` spawned processes. A worker that dies (SIGKILL, the kernel's OOM killer)
    stops the study with an error instead of a wait: ``multiprocessing.Pool`` loses the job
    of a killed worker and waits for its result forever (an Atari sweep of three hybrid runs
    side by side hung 80 min after the OOM killer took one of them); a
    ``ProcessPoolExecutor`` reports the death (``BrokenProcessPool``) and stops its other
    workers too, which resume from their checkpoints when the study is run again. Workers
    still busy when the caller stops early (an error, Ctrl-C) are terminated, as
    ``Pool.__exit__`` did, not waited for."""
    ex = ProcessPoolExecutor(
        workers,
        mp_context=mp.get_context("spawn"),
        initializer=_mark_worker,
        max_tasks_per_child=1 if fresh_process else None,
    )
    pending = {ex.submit(fn, job) for job in jobs}
    try:
        while pending:
            done, pending = wait(pending, timeout=0.5 if poll else None, return_when=FIRST_COMPLETED)
            if poll:
                poll()
            for fut in done:
                try:
                    result = fut.result()
                except BrokenProcessPool as err:
                    raise RuntimeError(
                        f"a worker process died in the middle of a job (killed by a signal, often the out-of-memory "
                        f"killer: {workers} jobs side by side may need more memory than this machine has); the "
                        "study stops here and its other jobs were stopped too. Run the same command again, with "
                        "fewer workers if memory was the cause: finished runs are kept and interrupted ones resume "
                        "from their checkpoints"
                    ) from err
                yield result
    finally:
        if pending:
            for proc in list((getattr(ex, "_processes", None) or {}).values()):
                proc.terminate()
        ex.shutdown(wait=True, cancel_futures=True)


#: Ray errors that mean the cluster failed rather than a job (checked by name: Ray versions differ)
_CLUSTER_ERRORS = ("LocalRayletDiedError", "RaySystemError", "ObjectLostError")


def _continue_hint(what: str) -> str:
    return (
        f"{what}; the study stops here. Run the same command again to continue: finished runs are kept "
        "and interrupted ones resume from their checkpoints"
    )


def run_jobs(
    fn: Callable[[Any], Any],
    jobs: Sequence[Any],
    *,
    launcher: str = "local",
    workers: int = 2,
    address: str | None = None,
    cpus_per_job: float = 1.0,
    max_retries: int = 2,
    fresh_process: bool = False,
    poll: Callable[[], None] | None = None,
) -> Iterator[Any]:
    """Runs ``fn(job)`` for every job and yields the results in the order they finish.

    Args:
        fn: a picklable function (module level for ``local``; Ray also takes closures). In the
            worker processes started here :func:`in_worker` is true, so a job may set that
            process's settings (:func:`~torchrl_hybrid.utils.process.configure_worker`);
            with ``workers=1`` jobs run in the caller's process and leave its settings alone.
        jobs: its arguments.
        launcher: ``"local"`` (``workers`` spawned processes; 1 = in this process) or
            ``"ray"`` (Ray tasks of ``cpus_per_job`` CPUs each; at most ``workers`` at a
            time on a local cluster started here, which gets ``workers * cpus_per_job`` CPUs).
        address: Ray only: the cluster to join (``"auto"``, ``"ray://host:10001"``, ...);
            ``None`` starts a local cluster with ``workers`` CPUs.
        max_retries: Ray only: how often a job whose worker died is started again.
        fresh_process: local, ``workers > 1``: each job in a new process, so a job's memory
            goes back to the OS before the next one starts (a worker that had finished one
            Atari hybrid run held 10-11 GB at 0.4M frames of its next one; it had held 4.9 GB
            at about 0.7M frames of its first).
        poll: local, ``workers > 1``: called about every 0.5 s while the jobs run (e.g. to move a
            progress bar from a queue the jobs write to).

    A local worker process that dies in the middle of a job stops the study with a
    ``RuntimeError`` that says how to continue (:func:`_run_local`).
    """
    if launcher not in LAUNCHERS:
        raise ValueError(f"launcher={launcher!r}: choose one of {LAUNCHERS}")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if not jobs:
        return
    if launcher == "local":
        if workers == 1:
            yield from map(fn, jobs)
            return
        yield from _run_local(fn, jobs, workers, fresh_process, poll)
        return
    ray = _ray()
    started_here = init_ray(address, num_cpus=int(math.ceil(workers * cpus_per_job)))
    remote = ray.remote(num_cpus=cpus_per_job, max_retries=max_retries)(_ray_job)
    pending = {remote.remote(fn, job): i for i, job in enumerate(jobs)}
    # the cluster itself failing (this node's raylet died, objects lost, ...): not the job's fault
    lost_cluster = tuple(getattr(ray.exceptions, n) for n in _CLUSTER_ERRORS if hasattr(ray.exceptions, n))
    try:
        while pending:
            try:
                done, _ = ray.wait(list(pending), num_returns=1)
            except lost_cluster as err:
                raise RuntimeError(_continue_hint(f"the Ray cluster failed ({type(err).__name__}: {err})")) from err
            i = pending.pop(done[0])
            try:
                yield ray.get(done[0])
            except (
                ray.exceptions.WorkerCrashedError,
                ray.exceptions.NodeDiedError,
                ray.exceptions.OutOfMemoryError,
            ) as err:
                raise RuntimeError(
                    _continue_hint(
                        f"job {i} of {len(jobs)} lost its worker {max_retries + 1} times ({type(err).__name__})"
                    )
                ) from err
            except lost_cluster as err:
                raise RuntimeError(_continue_hint(f"the Ray cluster failed ({type(err).__name__}: {err})")) from err
    finally:
        try:
            for ref in pending:
                ray.cancel(ref, force=True)
        except lost_cluster:  # nothing left to cancel them on; the error above says what to do
            pass
        if started_here:
            ray.shutdown()
