import csv
import json
import subprocess
import sys
from pathlib import Path

from torchrl_hybrid.experiments.gym_compare import GymCompareConfig, run_gym_compare

ROOT = Path(__file__).resolve().parents[1]
FROZEN = {"env": {"env_id": "FrozenLake-v1", "kwargs": {"map_name": "8x8", "is_slippery": False},
                  "max_episode_steps": 100},
          "total_frames": 640, "logger": {"log_every_frames": 320, "eval_episodes": 4, "final_eval_episodes": 4}}


def test_compare_runs_every_variant_and_seed_then_tabulates_with_intervals(tmp_path, capsys):
    cfg = GymCompareConfig(base=FROZEN, seeds=[0, 1, 2], out_dir=str(tmp_path), workers=1, command="cmd")
    result = run_gym_compare(cfg)
    assert [t["variant"] for t in result["table"]] == ["a2c", "hybrid_dual"]
    assert result["optimal"] == 1.0  # the built-in expert's own return on FrozenLake 8x8
    hybrid = result["table"][1]
    assert hybrid["seeds"] == 3 and "[" in hybrid["auc"] and "p = " in hybrid["auc_minus_a2c"]
    for f in ("README.md", "comparison.png", "curves.csv", "summary.csv"):
        assert (tmp_path / f).stat().st_size > 0
    rows = list(csv.DictReader((tmp_path / "curves.csv").open()))
    assert len(rows) == 2 * 3 * 3 and {r["variant"] for r in rows} == {"a2c", "hybrid_dual"}  # 3 points a run
    assert "Rerun: `cmd`" in (tmp_path / "README.md").read_text()
    capsys.readouterr()
    run_gym_compare(cfg)  # finished runs are kept, not run again
    assert "0 run(s) to do" in capsys.readouterr().out
    s = json.loads((tmp_path / "hybrid_dual_s1" / "summary.json").read_text())
    assert s["seed"] == 1 and s["variant"] == "hybrid_dual"


def test_compare_command_line_refuses_unknown_options(tmp_path):
    cmd = [sys.executable, str(ROOT / "recipes" / "compare.py"), "--config-name", "frozenlake8x8",
           f"out_dir={tmp_path}", "+compare.nope=1"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "unknown compare option(s) ['nope']" in r.stderr
