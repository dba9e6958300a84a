"""Every script in benchmarks/ runs, twice in a row, from a working directory that is not the
repository's, with tiny settings (issue 37): no fixed scratch path that the second run
collides with, no path taken relative to the working directory, and bad arguments refused
before any work with a one-line message.

Each benchmark runs as its own process (``sys.executable``), with one torch/OpenMP thread
(on a busy machine more threads only wait for each other). Twice: every benchmark that writes
anything (scratch runs, --out/--json files) and is cheap enough. Once: the read-only ones,
whose second run would only repeat the first (collectors.py, atari_action_usage.py), and,
marked ``slow``, the ones that cost 10-30 s a run even at their smallest (Ray's start,
torch.compile, the Atari training benchmarks)."""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
needs_ale = pytest.mark.skipif(
    importlib.util.find_spec("ale_py") is None, reason="needs ale-py (the project's [atari] extra)"
)
needs_ray = pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="needs Ray (the project's [ray] extra)")


def bench(script: str, *args: str, cwd: Path, times: int = 2, timeout: int = 300) -> list[str]:
    """Runs ``benchmarks/<script>`` ``times`` times in a row in ``cwd``; returns each run's stdout."""
    outs = []
    for i in range(times):
        p = subprocess.run(
            [sys.executable, str(BENCHMARKS / script), *args],
            cwd=cwd,
            env=ENV,
            capture_output=True,
            text=True,
            timeout=timeout,
        )
        assert p.returncode == 0, (
            f"run {i + 1} of {script} {' '.join(args)} exited {p.returncode}\n{p.stdout[-2000:]}\n{p.stderr[-4000:]}"
        )
        outs.append(p.stdout)
    return outs


def refused(script: str, *args: str, cwd: Path) -> str:
    """The one-line message of a refused command line (argparse's exit status 2)."""
    p = subprocess.run(
        [sys.executable, str(BENCHMARKS / script), *args], cwd=cwd, env=ENV, capture_output=True, text=True, timeout=120
    )
    assert p.returncode == 2, (p.returncode, p.stdout[-2000:], p.stderr[-2000:])
    assert "Traceback" not in p.stderr
    return p.stderr.strip().splitlines()[-1]


def test_every_benchmark_is_smoked_here():
    smoked = {m.group(1) for m in re.finditer(r'bench\(\s*"(\w+\.py)"', Path(__file__).read_text())}
    assert smoked == {p.name for p in BENCHMARKS.glob("*.py")}


def test_taxi_throughput(tmp_path):
    for out in bench(
        "taxi_throughput.py",
        "--seconds",
        "0.05",
        "--frames",
        "32",
        "--seeds",
        "2",
        "--eval-episodes",
        "1",
        cwd=tmp_path,
    ):
        assert re.search(r"2 seeds batched / 1 seed TabularEnv\s+[\d.]+x", out), out
    assert list(tmp_path.iterdir()) == []  # its scratch runs went to a temporary folder, now removed


def test_taxi_paths_agree(tmp_path):
    for out in bench(
        "taxi_paths_agree.py",
        "--seeds",
        "2",
        "--frames",
        "32",
        "--eval-episodes",
        "1",
        "--json",
        "r.json",
        cwd=tmp_path,
    ):
        assert re.search(r"final\s+TorchRL .* permutation p = [\d.]+", out), out
    assert json.loads((tmp_path / "r.json").read_text())["seeds"] == 2
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]
    # the permutation test needs 2 seeds a path: refused before any training (it failed in scipy after it)
    assert "needs >= 2" in refused("taxi_paths_agree.py", "--seeds", "1", cwd=tmp_path)


def test_collectors_once(tmp_path):
    # once: it only reads (its collector's worker process takes ~5 s to start)
    (out,) = bench(
        "collectors.py",
        "--envs",
        "Taxi-v4",
        "--workers",
        "1",
        "--batches",
        "2",
        "--num-envs",
        "2",
        "--no-ray",
        cwd=tmp_path,
        times=1,
    )
    assert re.search(r"multi_sync 1 worker\(s\)\s+\d+ frames/s\s+[\d.]+x", out), out
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
@needs_ray
def test_launchers_once(tmp_path):
    # once: Ray's local cluster alone takes ~10 s to start
    (out,) = bench(
        "launchers.py",
        "--seeds",
        "1",
        "--frames",
        "32",
        "--workers",
        "1",
        "--eval-episodes",
        "1",
        cwd=tmp_path,
        times=1,
    )
    assert re.search(r"ray\s+1\s+[\d.]+ s\s+[\d.]+x", out), out
    assert list(tmp_path.iterdir()) == []


@needs_ale
def test_atari_action_effect(tmp_path):
    for out in bench(
        "atari_action_effect.py", "--games", "Pong", "--states", "3", "--out", "effect.json", cwd=tmp_path
    ):
        assert re.search(r"Pong\s+6\s+[\d.]+%\s+[\d.]+%\s+[\d.]+", out), out
    (out,) = bench("atari_action_effect.py", "--from", "effect.json", cwd=tmp_path, times=1)
    assert "Pong" in out
    assert "no ROM for 'NotAGame'" in refused("atari_action_effect.py", "--games", "Pong", "NotAGame", cwd=tmp_path)


def test_atari_grad_norms(tmp_path):
    run = tmp_path / "compare" / "Breakout" / "hybrid_dual_s0"  # a finished comparison run, as written
    run.mkdir(parents=True)
    (run / "metrics.csv").write_text("frames,return_mean,grad_norm\n40000,0.0,2.0\n300000,0.0,1.0\n")
    (run / "config.json").write_text(json.dumps({"optim": {"max_grad_norm": 0.5}}))
    (run / "summary.json").write_text("{}")
    for out in bench("atari_grad_norms.py", "compare", "--games", "Breakout", "--json", "g.json", cwd=tmp_path):
        assert re.search(r"hybrid_dual_s0\s+2\.000\s+1\.000\s+nan\s+clip 0.5", out), out
    assert json.loads((tmp_path / "g.json").read_text())["Breakout"][0]["clip"] == 0.5


@pytest.fixture(scope="module")
def atari_runs(tmp_path_factory):
    """A tiny a2c run (model.pt), demos it recorded (with their true actions), and a tiny
    hybrid_dual run that learned from them (model.pt with the inverse model)."""
    pytest.importorskip("ale_py")
    import torch

    from torchrl_hybrid.families.atari import atari_config, record_demos, train_atari

    tmp = tmp_path_factory.mktemp("atari_runs")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)

    def tiny(name, **kw):
        return atari_config(
            {
                "out_dir": str(tmp / name),
                "device": "cpu",
                "total_frames": 256,
                "env": {"game": "Pong", "num_envs": 2, "num_threads": 1},
                "loss": {"n_steps": 4, "bc_start_frames": 64},
                "logger": {"progress_bar": False, "backend": "none", "log_every_frames": 128},
                **kw,
            }
        )

    try:
        train_atari(tiny("expert", variant="a2c"))
        record_demos(
            tmp / "expert" / "model.pt",
            tmp / "demos",
            num_trajectories=2,
            num_envs=2,
            max_steps=12,
            progress=False,
            device="cpu",
        )
        train_atari(tiny("hybrid", variant="hybrid_dual", demo={"path": str(tmp / "demos")}))
    finally:
        torch.set_num_threads(threads)
    return tmp


@needs_ale
def test_atari_action_usage_once(atari_runs, tmp_path):
    # once: it only reads
    (out,) = bench(
        "atari_action_usage.py", str(atari_runs / "expert" / "model.pt"), "--steps", "5", cwd=tmp_path, times=1
    )
    assert re.search(r"overall: +\{0: [\d.]+", out), out


@needs_ale
def test_atari_inverse_labels(atari_runs, tmp_path):
    args = ("--model", str(atari_runs / "hybrid" / "model.pt"), "--demos", str(atari_runs / "demos"), "--out", "l.json")
    for out in bench("atari_inverse_labels.py", *args, cwd=tmp_path):
        assert re.search(r"label accuracy [\d.]+%", out), out
    assert [p.name for p in tmp_path.iterdir()] == ["l.json"]


@pytest.mark.slow
@needs_ale
def test_atari_idm_learning_once(tmp_path):
    # once: three runs in a worker process, each starting its games (~15 s at the smallest)
    (out,) = bench(
        "atari_idm_learning.py", "--frames", "640", "--workers", "1", "--num-envs", "2", cwd=tmp_path, times=1
    )
    assert re.search(r"mlp\n +640 frames  loss [\d.]+  accuracy [\d.]+", out), out
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
@needs_ale
def test_atari_throughput_once(tmp_path):
    # once: its demos (an untrained expert's run and recording) and two runs, ~30 s at the smallest
    (out,) = bench(
        "atari_throughput.py", "--steps", "10", "--num-envs", "2", "--threads", "1", "--no-sb3", cwd=tmp_path, times=1
    )
    assert re.search(r"ours: hybrid_dual / floor: [\d.]+", out), out
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
@needs_ale
def test_atari_profile_once(tmp_path):
    # once: as atari_throughput (it builds the same runs)
    (out,) = bench("atari_profile.py", "--steps", "10", "--num-envs", "2", "--threads", "1", cwd=tmp_path, times=1)
    assert re.search(r"= agent steps/s\s+\d+\s+\d+", out), out
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_atari_compile_once(tmp_path):
    # once: torch.compile's first compilation of the CNN takes ~20 s on a CPU
    (out,) = bench("atari_compile.py", "--rounds", "1", "--reps", "1", "--threads", "1", cwd=tmp_path, times=1)
    assert re.search(r"default\s+[\d.]+\s+[\d.]+\s+[\d.]+\s+[\d.]+x\s+[\d.]+x", out), out
