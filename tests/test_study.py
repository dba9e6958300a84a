"""A study (compare, atari_compare, taxi_sweep) is a unit like a run: it never reports or
overwrites runs made with other settings, defaults to a fresh folder, and holds a lock."""

import dataclasses
import json
from pathlib import Path

import pytest

from torchrl_hybrid.experiments.study import STUDY_FILE, open_study, settings_diff

FROZEN = {
    "env": {"env_id": "FrozenLake-v1", "kwargs": {"map_name": "8x8", "is_slippery": False}, "max_episode_steps": 100},
    "total_frames": 320,
    "logger": {"log_every_frames": 320, "eval_episodes": 2, "final_eval_episodes": 2},
}


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != ".study.lock"
    }


def test_a_compare_rerun_with_other_settings_is_refused_then_rerun_with_overwrite(tmp_path, capsys):
    from torchrl_hybrid.experiments.gym_compare import GymCompareConfig, run_gym_compare

    cfg = GymCompareConfig(
        base=FROZEN, variants=["a2c"], seeds=[0], out_dir=str(tmp_path), workers=1, command="cmd one"
    )
    run_gym_compare(cfg)
    record = json.loads((tmp_path / STUDY_FILE).read_text())
    assert record["kind"] == "gym_compare"
    (session,) = record["sessions"]  # where the runs trained: commit, command, machine
    assert {"commit", "command", "date", "machine"} <= set(session)
    assert {"cpu", "cores", "torch", "torch_threads"} <= set(session["machine"])
    assert "Made at commit" in (tmp_path / "README.md").read_text()
    before = _snapshot(tmp_path)
    changed = GymCompareConfig(
        base={**FROZEN, "optim": {"lr": 0.01}},
        variants=["a2c"],
        seeds=[0],
        out_dir=str(tmp_path),
        workers=1,
        command="cmd two",
    )
    with pytest.raises(ValueError, match=r"1 run\(s\) in .* other settings .*a2c_s0: optim.lr: 0.001 -> 0.01"):
        run_gym_compare(changed)
    assert _snapshot(tmp_path) == before  # nothing rewritten: not the README's Rerun line, not a run
    capsys.readouterr()
    run_gym_compare(dataclasses.replace(changed, overwrite=True))
    assert "1 run(s) to do" in capsys.readouterr().out
    assert json.loads((tmp_path / "a2c_s0" / "config.json").read_text())["optim"]["lr"] == 0.01
    assert "Rerun: `cmd two`" in (tmp_path / "README.md").read_text()
    # analyse_only: nothing trains; the finished runs are tabulated, the missing ones named
    capsys.readouterr()
    result = run_gym_compare(dataclasses.replace(changed, seeds=[0, 1], analyse_only=True))
    assert "analyse_only: 1 run(s) not finished, left out: a2c_s1" in capsys.readouterr().out
    assert not (tmp_path / "a2c_s1").exists() and result["table"][0]["seeds"] == 1
    # a damaged summary.json is named, not a bare JSON error
    (tmp_path / "a2c_s0" / "summary.json").write_text("")
    with pytest.raises(ValueError, match=r"a2c_s0/summary.json: malformed run summary"):
        run_gym_compare(dataclasses.replace(changed, overwrite=False))


def test_an_atari_compare_refuses_finished_runs_of_another_base_setting(tmp_path):
    from torchrl_hybrid.experiments.atari_compare import CompareConfig, run_compare
    from torchrl_hybrid.families.atari import atari_config

    run = tmp_path / "Pong" / "a2c_s0"
    run.mkdir(parents=True)
    made = atari_config(
        {"variant": "a2c", "seed": 0, "total_frames": 640, "out_dir": str(run), "env": {"game": "Pong"}}
    )
    (run / "config.json").write_text(json.dumps(dataclasses.asdict(made)))
    (run / "summary.json").write_text("{}")
    before = _snapshot(tmp_path)
    cfg = CompareConfig(
        games=["Pong"],
        variants=["a2c"],
        seeds=[0],
        total_frames=640,
        out_dir=str(tmp_path),
        workers=1,
        base={"loss": {"entropy_coeff": 0.5}},
    )
    with pytest.raises(ValueError, match=r"Pong/a2c_s0: loss.entropy_coeff: 0.01 -> 0.5"):
        run_compare(cfg)
    assert _snapshot(tmp_path) == {**before, STUDY_FILE: b'{\n  "kind": "atari_compare"\n}'}


def test_studies_default_to_a_fresh_folder_never_a_committed_one():
    from torchrl_hybrid.experiments.atari_compare import CompareConfig
    from torchrl_hybrid.experiments.taxi_sweep import SweepConfig

    assert SweepConfig().out_dir.startswith("outputs/taxi_sweep/")
    assert CompareConfig().out_dir.startswith("outputs/atari_compare/")
    from hydra import compose, initialize_config_dir

    from torchrl_hybrid.configs import register_configs

    register_configs()  # the schema of taxi.yaml and its presets
    root = Path(__file__).resolve().parents[1] / "recipes" / "config"
    with initialize_config_dir(config_dir=str(root), version_base=None):
        for name in ("taxi_sweep", "atari_compare", "taxi", "cartpole"):
            assert compose(config_name=name, return_hydra_config=True).out_dir.startswith("outputs/"), name


def test_a_sweep_over_a_finished_sweep_of_other_settings_is_refused(tmp_path):
    from torchrl_hybrid.experiments.taxi_sweep import SweepConfig, run_sweep

    meta = {"groups": ["agents", "ranks", "noise"], "seeds": 16, "total_frames": 80000, "base": {}}
    (tmp_path / "runs.json").write_text(json.dumps({"meta": meta, "runs": {}}))
    (tmp_path / "README.md").write_text("the committed study")
    before = _snapshot(tmp_path)
    cfg = SweepConfig(groups=["ranks"], seeds=2, total_frames=2000, out_dir=str(tmp_path), workers=1)
    with pytest.raises(
        ValueError,
        match=r"finished sweep with other settings \(groups: \['agents', 'ranks', "
        r"'noise'\] -> \['ranks'\]; seeds: 16 -> 2; total_frames: 80000 -> 2000",
    ):
        run_sweep(cfg, show_progress=False)
    assert _snapshot(tmp_path) == {**before, STUDY_FILE: b'{\n  "kind": "taxi_sweep"\n}'}


def test_a_study_folder_is_taken_by_one_study_of_one_kind(tmp_path):
    with open_study(tmp_path / "s", "gym_compare", looks_like=lambda p: False):
        with pytest.raises(ValueError, match="in use by another study"):
            open_study(tmp_path / "s", "gym_compare", looks_like=lambda p: False)
    open_study(tmp_path / "s", "gym_compare", looks_like=lambda p: False).close()  # released
    with pytest.raises(ValueError, match="holds a 'gym_compare' study .* not a 'taxi_sweep' one"):
        open_study(tmp_path / "s", "taxi_sweep", looks_like=lambda p: True)
    other = tmp_path / "notes"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match=r"holds files that are not a gym_compare study \(notes.txt"):
        open_study(other, "gym_compare", looks_like=lambda p: False)
    assert not (other / STUDY_FILE).exists()
    open_study(other, "gym_compare", looks_like=lambda p: False, overwrite=True).close()
    assert (other / "notes.txt").read_text() == "mine"  # beside, not removed
    (tmp_path / "file").write_text("")
    with pytest.raises(ValueError, match="is a file, not a folder"):
        open_study(tmp_path / "file", "gym_compare", looks_like=lambda p: True)


def test_settings_diff_names_each_setting_and_reads_missing_ones_as_defaults():
    saved = {"optim": {"lr": 0.001}, "seed": 0, "threads": 1}
    now = {"optim": {"lr": 0.01, "eps": 1e-5}, "seed": 0, "threads": 4}
    assert settings_diff(saved, now, ["optim", "seed"], defaults={"optim": {"eps": 1e-5}}) == [
        "optim.lr: 0.001 -> 0.01"
    ]
    assert settings_diff(saved, now, ["optim.eps"]) == ["optim.eps: None -> 1e-05"]
    assert settings_diff(saved, now, ["optim"], ignore=["optim.lr", "optim.eps"]) == []
