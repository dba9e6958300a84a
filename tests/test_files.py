"""Nothing lost, nothing silently wrong: out_dir rules, locks, resume checks, damaged files."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from conftest import TEST_DEVICE  # the `device` fixture's value: cpu in CI, cuda under make test-cuda
from tensordict import TensorDict

from torchrl_hybrid.data import load_demos, save_demos
from torchrl_hybrid.families.gym import config_from_dict, train_gym
from torchrl_hybrid.utils.files import check_memmap_folder, prepare_out_dir

ROOT = Path(__file__).resolve().parents[1]


def tiny(out, **kw):
    d = {
        "total_frames": 640,
        "out_dir": str(out),
        "device": TEST_DEVICE,
        "logger": {
            "log_every_frames": 320,
            "eval_episodes": 8,
            "final_eval_episodes": 8,
            "progress_bar": False,
            "backend": "csv",
        },
    }
    d.update(kw)
    return config_from_dict(d)


def _demos(path):
    td = TensorDict(
        {
            "observation": torch.arange(6),
            ("next", "observation"): torch.arange(1, 7),
            "step": torch.zeros(6, dtype=torch.long),
        },
        [6],
    )
    return save_demos(td, path, {"env_id": "Taxi-v4"})


def test_truncated_demo_file_is_refused_and_left_as_it_was(tmp_path):
    path = _demos(tmp_path / "demos")
    f = path / "next" / "observation.memmap"
    f.write_bytes(f.read_bytes()[:20])
    with pytest.raises(ValueError, match=r"observation.memmap holds 20 bytes but .* describes 48"):
        load_demos(path)
    assert f.stat().st_size == 20  # never written to


def test_malformed_metadata_names_the_file(tmp_path):
    path = _demos(tmp_path / "demos")
    (path / "metadata.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"metadata.json: malformed demo metadata"):
        load_demos(path)
    (path / "meta.json").write_text('{"observation": ')
    with pytest.raises(ValueError, match=r"demos/meta.json: malformed TensorDict metadata"):
        check_memmap_folder(path)


def test_demos_are_not_written_over_other_demos(tmp_path):
    _demos(tmp_path / "demos")
    with pytest.raises(ValueError, match="already exists and is not empty; pass overwrite=true"):
        _demos(tmp_path / "demos")
    td = TensorDict({"observation": torch.arange(3), ("next", "observation"): torch.arange(1, 4)}, [3])
    save_demos(td, tmp_path / "demos", overwrite=True)
    assert load_demos(tmp_path / "demos")[0].shape == (3,)


def test_finished_run_is_not_overwritten_unless_asked(tmp_path):
    first = train_gym(tiny(tmp_path))
    model = (tmp_path / "model.pt").read_bytes()
    with pytest.raises(ValueError, match=r"holds a finished run \(summary.json, model.pt, metrics.csv"):
        train_gym(tiny(tmp_path, seed=1))
    assert (tmp_path / "model.pt").read_bytes() == model
    assert json.loads((tmp_path / "summary.json").read_text())["seed"] == first["seed"] == 0
    s = train_gym(tiny(tmp_path, seed=1, overwrite=True))
    assert s["seed"] == 1 and json.loads((tmp_path / "summary.json").read_text())["seed"] == 1


def test_resume_over_results_without_a_checkpoint_is_refused(tmp_path):
    train_gym(
        tiny(
            tmp_path,
            logger={
                "checkpoint": False,
                "progress_bar": False,
                "eval_episodes": 8,
                "final_eval_episodes": 8,
                "log_every_frames": 320,
            },
        )
    )
    with pytest.raises(ValueError, match="resume=true but .* has no checkpoint/ to resume from"):
        train_gym(tiny(tmp_path, resume=True, total_frames=1280))
    with pytest.raises(ValueError, match="contradict"):
        train_gym(tiny(tmp_path, resume=True, overwrite=True))


def test_a_second_run_on_a_folder_in_use_is_refused(tmp_path):
    with prepare_out_dir(tmp_path / "run"):
        with pytest.raises(ValueError, match="is in use by another run"):
            train_gym(tiny(tmp_path / "run"))
    assert not (tmp_path / "run" / "metrics.csv").exists()
    assert train_gym(tiny(tmp_path / "run"))["frames"] == 640  # free again once the first run let go


def test_taxi_resumes_and_refuses_changed_settings(tmp_path, capsys):
    train_gym(tiny(tmp_path))
    with pytest.raises(ValueError, match=r"other settings for \['optim.lr'\] \(optim.lr: 0.001 -> 0.01"):
        train_gym(tiny(tmp_path, resume=True, total_frames=1280, optim={"lr": 0.01}))
    capsys.readouterr()
    logger = {
        "log_every_frames": 320,
        "eval_episodes": 8,
        "final_eval_episodes": 8,
        "progress_bar": True,
        "backend": "csv",
    }
    s = train_gym(tiny(tmp_path, resume=True, total_frames=1280, logger=logger))
    assert s["frames"] == 1280 and s["resumed_from_frames"] == 640
    bar = capsys.readouterr().err.split("continuing from 640 frames", 1)[1]
    assert "| 1280/1280 [" in bar  # the progress bar goes on from where the run resumed (640), not from 0
    frames = [int(r.split(",")[0]) for r in (tmp_path / "metrics.csv").read_text().splitlines()[1:]]
    assert frames == sorted(set(frames)) and frames[-1] == 1280


def test_resume_refuses_a_damaged_checkpoint_or_missing_settings(tmp_path):
    train_gym(tiny(tmp_path))
    (tmp_path / "config.json").rename(tmp_path / "config.json.bak")
    with pytest.raises(ValueError, match="has no config.json beside it"):
        train_gym(tiny(tmp_path, resume=True, total_frames=1280))
    (tmp_path / "config.json.bak").rename(tmp_path / "config.json")
    f = max((tmp_path / "checkpoint").rglob("*.memmap"), key=lambda p: p.stat().st_size)
    f.write_bytes(f.read_bytes()[:-8])
    with pytest.raises(ValueError, match=r"\.memmap holds .* bytes but .* the file is truncated"):
        train_gym(tiny(tmp_path, resume=True, total_frames=1280))


def test_a_killed_run_resumes_from_its_checkpoint(tmp_path):
    out = tmp_path / "run"
    cmd = [
        sys.executable,
        str(ROOT / "recipes" / "taxi.py"),
        f"out_dir={out}",
        "device=cpu",
        "total_frames=8000",
        "logger.progress_bar=false",
        "logger.log_every_frames=1000",
        "logger.eval_episodes=8",
        "logger.final_eval_episodes=8",
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 240
    while not (out / "checkpoint" / "manifest.json").exists():
        assert proc.poll() is None, proc.stderr.read()[-2000:]
        assert time.time() < deadline, "no checkpoint within 240 s"
        time.sleep(0.2)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (out / "summary.json").exists()
    # the killed run's lock died with it; a plain rerun would start over its curve: refused
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "holds a started run" in r.stderr, r.stderr[-2000:]
    r = subprocess.run(cmd + ["resume=true"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 8000 and summary["resumed_from_frames"] > 0


def test_a_run_killed_while_publishing_its_checkpoint_resumes_from_the_previous_one(tmp_path):
    # TorchRL writes a checkpoint into .checkpoint.stage-*, moves the old one to
    # .checkpoint.backup-*, then the stage into place: the state a kill leaves between
    # the two renames, with a half-written stage beside it
    train_gym(tiny(tmp_path))
    (tmp_path / "checkpoint").rename(tmp_path / ".checkpoint.backup-0123")
    (tmp_path / ".checkpoint.stage-4567" / "components").mkdir(parents=True)
    s = train_gym(tiny(tmp_path, resume=True, total_frames=1280))
    assert s["frames"] == 1280 and s["resumed_from_frames"] == 640


@pytest.mark.parametrize("kw", [{}, {"loss": {"bc_start_frames": 480}}])
def test_taxi_resume_is_bit_exact(tmp_path, kw):
    straight = train_gym(tiny(tmp_path / "straight", total_frames=1280, **kw))
    train_gym(tiny(tmp_path / "pieces", total_frames=640, **kw))
    resumed = train_gym(tiny(tmp_path / "pieces", total_frames=1280, resume=True, **kw))
    a = torch.load(tmp_path / "straight" / "model.pt", weights_only=False)
    b = torch.load(tmp_path / "pieces" / "model.pt", weights_only=False)
    for part in ("actor", "critic", "inverse_model"):
        for k in a[part]:
            assert torch.equal(a[part][k], b[part][k]), (part, k)
    assert resumed["final_return"] == straight["final_return"]
    # the last row's losses and evaluations (return_mean and episodes count the episodes
    # since the previous row, and the first piece wrote an extra row where it ended)
    import csv

    last = [list(csv.DictReader((tmp_path / d / "metrics.csv").open()))[-1] for d in ("straight", "pieces")]
    for k in last[0]:
        if k not in ("return_mean", "episodes", "time_s"):
            assert last[0][k] == last[1][k], k


def test_a_truncated_checkpoint_manifest_is_named(tmp_path):
    train_gym(tiny(tmp_path))
    manifest = tmp_path / "checkpoint" / "manifest.json"
    manifest.write_text(manifest.read_text()[:40])
    with pytest.raises(ValueError, match=r"checkpoint/manifest.json: malformed checkpoint manifest"):
        train_gym(tiny(tmp_path, resume=True, total_frames=1280))
