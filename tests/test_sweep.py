import json
import os
import subprocess
import sys
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

from torchrl_hybrid.experiments.taxi_sweep import SweepConfig, configurations, parameter_table, run_sweep

ROOT = Path(__file__).resolve().parents[1]


def test_configurations_cover_the_paper():
    confs = configurations(["agents", "ranks", "noise"])
    assert len(confs) == 20  # 6 agents + ranks 1 and 4 + 12 noise settings (a2c, rank 2 shared)
    assert confs["hybrid_dual_rank4"] == {"variant": "hybrid_dual", "rank": 4}
    assert confs["bc_dual_eta0.5"] == {"variant": "bc_dual", "demo": {"eta": 0.5}}
    with pytest.raises(ValueError, match="unknown group"):
        configurations(["figure_z"])


def test_parameter_table_computes_the_papers_ratio():
    rows = {r["model"]: r for r in parameter_table()}
    assert rows["full tensor |S| x |A| x |S|"]["factor parameters"] == 1_500_000
    assert rows["dual, rank 2 (M_r, N_r)"]["factor parameters"] == 65_536
    assert rows["dual, rank 2 (M_r, N_r)"]["% of full tensor"] == 4.37


@pytest.fixture(scope="module")
def tiny_sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep")
    cfg = SweepConfig(
        groups=("agents", "ranks", "noise"),
        seeds=2,
        total_frames=640,
        out_dir=str(out),
        workers=2,
        base={"logger": {"log_every_frames": 320, "eval_episodes": 8, "final_eval_episodes": 8}},
    )
    run_sweep(cfg, show_progress=False)
    return out


def test_sweep_writes_figures_tables_and_claims(tiny_sweep):
    out = tiny_sweep
    for f in (
        "fig_agents.png",
        "fig_ranks.png",
        "fig_noise.png",
        "fig_action_prediction.png",
        "curves.csv",
        "final.csv",
        "parameters.csv",
        "runs.json",
        "README.md",
    ):
        assert (out / f).exists(), f
    data = json.loads((out / "runs.json").read_text())
    assert len(data["runs"]) == 20 and all(len(v) == 2 for v in data["runs"].values())
    readme = (out / "README.md").read_text()
    assert readme.count("| C") == 5 and "4.37" in readme
    assert len((out / "final.csv").read_text().splitlines()) == 1 + 40


def test_reproduction_notebook_runs_on_a_sweep(tiny_sweep, monkeypatch):
    path = ROOT / "notebooks" / "02_taxi_reproduction.ipynb"
    monkeypatch.setenv("TAXI_RESULTS", str(tiny_sweep))
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}).execute()


def test_sweep_command_line_subset(tmp_path):
    cmd = [
        sys.executable,
        str(ROOT / "recipes" / "taxi_sweep.py"),
        "groups=[ranks]",
        "seeds=1",
        "total_frames=320",
        f"out_dir={tmp_path}",
        "workers=1",
        "+base.logger.eval_episodes=4",
        "+base.logger.final_eval_episodes=4",
    ]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert res.returncode == 0, res.stderr[-2000:]
    assert set(json.loads((tmp_path / "runs.json").read_text())["runs"]) == {
        "hybrid_dual_rank1",
        "hybrid_dual",
        "hybrid_dual_rank4",
        "a2c",
    }
    bad = subprocess.run(cmd[:2] + ["seeds=0", f"out_dir={tmp_path}/x"], capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and "seeds must be >= 1" in bad.stderr


def test_an_interrupted_sweep_runs_only_the_missing_configurations(tmp_path, capsys):
    base = {"logger": {"log_every_frames": 320, "eval_episodes": 4, "final_eval_episodes": 4}}
    cfg = SweepConfig(groups=("ranks",), seeds=2, total_frames=320, out_dir=str(tmp_path), workers=1, base=base)
    first = run_sweep(cfg, show_progress=False)
    assert not (tmp_path / "configs").exists()  # a finished sweep keeps everything in runs.json
    # the state an interrupted sweep leaves: a2c finished (its file written), the others not
    from torchrl_hybrid.utils.config import merge_dicts

    settings = [
        merge_dicts(
            merge_dicts(
                merge_dicts({"total_frames": 320, "logger": {"progress_bar": False}}, base), {"variant": "a2c"}
            ),
            {"seed": s, "out_dir": f"{tmp_path}/runs/a2c/seed_{s}"},
        )
        for s in range(2)
    ]
    marker = [dict(r, final_return=123.0) for r in first["a2c"]]
    # the same sweep again: analysed, nothing trained
    capsys.readouterr()
    finals = lambda res: {k: [r["final_return"] for r in v] for k, v in res.items()}  # noqa: E731
    assert finals(run_sweep(cfg, show_progress=False)) == finals(first)
    assert "holds this sweep already" in capsys.readouterr().out
    (tmp_path / "runs.json").unlink()  # an interrupted sweep has none yet
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "a2c.json").write_text(json.dumps({"settings": settings, "summaries": marker}))
    capsys.readouterr()
    again = run_sweep(cfg, show_progress=False)
    assert "1 configuration(s) already done" in capsys.readouterr().out
    assert [r["final_return"] for r in again["a2c"]] == [123.0, 123.0]  # kept, not run again
    assert set(again) == {"a2c", "hybrid_dual", "hybrid_dual_rank1", "hybrid_dual_rank4"}
