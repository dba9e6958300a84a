"""Studies on Ray: runs as Ray tasks on a local 2-CPU cluster, and a worker killed in the
middle of a run (tiny FrozenLake runs)."""

import csv
import json
from pathlib import Path

import pytest

from torchrl_hybrid.utils.launch import run_jobs

ray = pytest.importorskip("ray")

FROZEN = {
    "env": {"env_id": "FrozenLake-v1", "kwargs": {"map_name": "8x8", "is_slippery": False}, "max_episode_steps": 100},
    "total_frames": 640,
    "logger": {"log_every_frames": 320, "eval_episodes": 4, "final_eval_episodes": 4},
}


@pytest.fixture(scope="module")
def cluster():
    from torchrl_hybrid.utils.launch import init_ray

    init_ray(num_cpus=2)
    yield
    ray.shutdown()


def test_run_jobs_gives_every_result_once_locally_and_on_ray(cluster):
    square = lambda x: x * x  # noqa: E731 (a closure: Ray ships it by value to its workers)
    assert sorted(run_jobs(square, [1, 2, 3], launcher="local", workers=1)) == [1, 4, 9]
    assert sorted(run_jobs(square, list(range(6)), launcher="ray", workers=2)) == [0, 1, 4, 9, 16, 25]
    with pytest.raises(ValueError, match="launcher='slurm'"):
        list(run_jobs(square, [1], launcher="slurm"))


def _pid(_job):
    import os
    import time

    time.sleep(0.2)  # so that both workers take jobs
    return os.getpid()


def test_fresh_process_runs_each_local_job_in_a_new_process():
    """Atari runs side by side: a worker that ran one run held twice its memory in the next;
    with fresh_process each job gets its own process."""
    pids = list(run_jobs(_pid, range(4), launcher="local", workers=2, fresh_process=True))
    assert len(set(pids)) == 4
    pids = list(run_jobs(_pid, range(4), launcher="local", workers=2))
    assert len(set(pids)) == 2  # the default reuses the two workers


def _killing(target: str, times: int):
    """A run function that SIGKILLs its own worker ``times`` times, right after the run
    named ``target`` wrote its first checkpoint (in the middle of the run)."""

    def run(d):
        import os
        import signal
        import threading
        import time

        from torchrl_hybrid.experiments.gym_compare import run_one

        out = Path(d["out_dir"])
        kills = out.parent / f"kills_{out.name}"
        n = len(kills.read_text()) if kills.exists() else 0
        if out.name == target and n < times:

            def watch():
                while not (out / "checkpoint").exists():
                    time.sleep(0.002)
                with kills.open("a") as f:
                    f.write("x")
                os.kill(os.getpid(), signal.SIGKILL)

            threading.Thread(target=watch, daemon=True).start()
        return run_one(d)

    return run


def test_a_sweep_on_ray_survives_a_worker_killed_mid_run(cluster, tmp_path):
    from torchrl_hybrid.experiments.gym_compare import GymCompareConfig, run_gym_compare

    cfg = GymCompareConfig(
        base=FROZEN, variants=["hybrid_dual"], seeds=[0, 1], out_dir=str(tmp_path), workers=2, launcher="ray"
    )
    result = run_gym_compare(cfg, run_fn=_killing("hybrid_dual_s1", times=1))
    assert (tmp_path / "kills_hybrid_dual_s1").read_text() == "x"  # the worker was killed once
    assert [(t["variant"], t["seeds"]) for t in result["table"]] == [("hybrid_dual", 2)]
    assert sorted(p.name for p in tmp_path.iterdir() if p.is_dir()) == ["hybrid_dual_s0", "hybrid_dual_s1"]
    s = json.loads((tmp_path / "hybrid_dual_s1" / "summary.json").read_text())
    assert s["frames"] == 640 and s["resumed_from_frames"] > 0  # the retry went on from the checkpoint
    frames = [int(r["frames"]) for r in csv.DictReader((tmp_path / "hybrid_dual_s1" / "metrics.csv").open())]
    assert frames == sorted(set(frames)) and frames[-1] == 640  # no row logged twice, none missing at the end


def test_a_worker_that_keeps_dying_stops_the_study_with_how_to_continue(cluster, tmp_path):
    from torchrl_hybrid.experiments.gym_compare import GymCompareConfig, run_gym_compare

    cfg = GymCompareConfig(
        base=FROZEN, variants=["a2c"], seeds=[0], out_dir=str(tmp_path), workers=1, launcher="ray", max_retries=1
    )
    with pytest.raises(RuntimeError, match="lost its worker 2 times.*Run the same command again"):
        run_gym_compare(cfg, run_fn=_killing("a2c_s0", times=5))
    # the same study without faults finishes from where it stopped
    result = run_gym_compare(cfg)
    assert result["table"][0]["seeds"] == 1
    assert json.loads((tmp_path / "a2c_s0" / "summary.json").read_text())["resumed_from_frames"] > 0


def test_the_taxi_sweep_on_ray(cluster, tmp_path):
    from torchrl_hybrid.experiments.taxi_sweep import SweepConfig, run_sweep

    cfg = SweepConfig(
        groups=("ranks",),
        seeds=2,
        total_frames=320,
        out_dir=str(tmp_path),
        workers=2,
        launcher="ray",
        base={"logger": {"log_every_frames": 320, "eval_episodes": 4, "final_eval_episodes": 4}},
    )
    results = run_sweep(cfg, show_progress=False)
    assert set(results) == {"a2c", "hybrid_dual", "hybrid_dual_rank1", "hybrid_dual_rank4"}
    assert all(len(v) == 2 for v in results.values()) and (tmp_path / "README.md").exists()
