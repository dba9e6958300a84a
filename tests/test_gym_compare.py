import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

from torchrl_hybrid.experiments.gym_compare import GymCompareConfig, run_gym_compare

ROOT = Path(__file__).resolve().parents[1]
FROZEN = {
    "env": {"env_id": "FrozenLake-v1", "kwargs": {"map_name": "8x8", "is_slippery": False}, "max_episode_steps": 100},
    "total_frames": 640,
    "logger": {"log_every_frames": 320, "eval_episodes": 4, "final_eval_episodes": 4},
}


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
    cmd = [
        sys.executable,
        str(ROOT / "recipes" / "compare.py"),
        "--config-name",
        "frozenlake8x8",
        f"out_dir={tmp_path}",
        "+compare.nope=1",
    ]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "unknown compare option(s) ['nope']" in r.stderr


def test_frames_to_the_expert_are_measured_from_the_random_policy_up():
    from torchrl_hybrid.experiments.gym_compare import random_policy_return, reach_threshold

    assert reach_threshold(-500.0, -176.0, 0.9) == pytest.approx(-208.4)  # not 0.9 x -176 = -158.4
    assert reach_threshold(22.0, 500.0, 0.9) == pytest.approx(452.2)
    assert 15 < random_policy_return("CartPole-v1", {}, 500, episodes=20) < 30  # the random policy's ~22


def test_named_and_own_arms_run_with_their_settings_and_against_their_base(tmp_path):
    cfg = GymCompareConfig(
        base=FROZEN,
        variants=["hybrid_dual", "hybrid_dual_clip_apart", "mine"],
        seeds=[0, 1],
        arms={"mine": {"variant": "hybrid_dual", "base": "hybrid_dual", "demo": {"batch_size": 8}}},
        out_dir=str(tmp_path),
        workers=1,
    )
    result = run_gym_compare(cfg)
    settings = {a: json.loads((tmp_path / f"{a}_s0" / "config.json").read_text()) for a in cfg.variants}
    assert settings["hybrid_dual_clip_apart"]["optim"]["clip"] == "per_term"
    assert settings["mine"]["demo"]["batch_size"] == 8 and settings["mine"]["variant"] == "hybrid_dual"
    assert settings["hybrid_dual"]["optim"]["clip"] == "global"
    rows = {t["variant"]: t for t in result["table"]}
    assert rows["mine"]["option_effect"].startswith("auc − hybrid_dual: ")
    assert rows["hybrid_dual"]["idm_accuracy_expert_end"] != "" and rows["hybrid_dual"]["entropy_end"] != ""
    assert result["threshold"] == pytest.approx(result["random_return"] + 0.9 * (1.0 - result["random_return"]))
    for bad, match in ((["nope"], r"unknown variant\(s\) or arm\(s\) \['nope'\]"),):
        with pytest.raises(ValueError, match=match):
            GymCompareConfig(base=FROZEN, variants=bad, out_dir=str(tmp_path)).validate()
    with pytest.raises(ValueError, match="an arm cannot take a variant's name"):
        GymCompareConfig(base=FROZEN, arms={"a2c": {"variant": "a2c"}}, out_dir=str(tmp_path)).validate()
    with pytest.raises(ValueError, match="must be a mapping with variant"):
        GymCompareConfig(base=FROZEN, arms={"x": {"variant": "ppo"}}, out_dir=str(tmp_path)).validate()


def test_headline_states_both_goals_from_each_comparisons_numbers(tmp_path):
    from torchrl_hybrid.experiments.headline import headline_markdown, headline_rows, update_readme_block

    def arm(variant, auc, frames, base=None):
        return {
            "variant": variant,
            "base": base,
            "seeds": list(range(len(auc))),
            "auc": auc,
            "final": auc,
            "frames_to_reach": frames,
            "budget": 100_000.0,
            "idm_accuracy_expert_end": [None] * len(auc),
            "entropy_end": [None] * len(auc),
        }

    (tmp_path / "env").mkdir()
    (tmp_path / "env" / "summary.json").write_text(
        json.dumps(
            {
                "env_id": "X",
                "expert_return": 500.0,
                "random_return": 20.0,
                "threshold": 452.0,
                "reach_share": 0.9,
                "reference": "a2c",
                "arms": {
                    "a2c": arm("a2c", [100, 110, 120, 105, 115], [80_000, 90_000, None, 70_000, 85_000]),
                    "hybrid_dual": arm("hybrid_dual", [105, 112, 118, 100, 111], [None] * 5),
                    "hybrid_dual_utd4": arm(
                        "hybrid_dual",
                        [300, 310, 290, 305, 295],
                        [30_000, 35_000, 40_000, 30_000, 32_000],
                        base="hybrid_dual",
                    ),
                    "hybrid_true": arm("hybrid_true", [290, 320, 300, 310, 300], [30_000] * 5),
                },
            }
        )
    )
    (row,) = headline_rows({"X": tmp_path / "env"})
    assert row["best"]["arm"] == "hybrid_dual_utd4"  # the best arm with inferred labels, not the oracle
    assert row["base_frames"] == (80_000 + 90_000 + 100_000 + 70_000 + 85_000) / 5  # never reached: the budget
    assert row["faster"] is True and row["as_good_as_true"] is True
    assert row["paper"]["diff"].startswith("-0.8 [")
    table = headline_markdown([row])
    assert "`hybrid_dual_utd4`" in table and "| **yes** | **yes** |" in table
    readme = tmp_path / "README.md"
    readme.write_text("intro\n<!-- headline:start -->\nold\n<!-- headline:end -->\nrest\n")
    update_readme_block(readme, table)
    assert readme.read_text().startswith("intro\n<!-- headline:start -->\n| env |") and "old" not in readme.read_text()
    # a PPO base beside: its own row, each arm held against the base it runs on (its rl)
    summary = json.loads((tmp_path / "env" / "summary.json").read_text())
    summary["arms"].update(
        {
            "ppo": {**arm("a2c", [400] * 5, [20_000] * 5), "rl": "ppo"},
            "hybrid_dual_ppo": {**arm("hybrid_dual", [410] * 5, [9_000] * 5, "ppo"), "rl": "ppo"},
        }
    )
    (tmp_path / "env" / "summary.json").write_text(json.dumps(summary))
    a2c_row, ppo_row = headline_rows({"X": tmp_path / "env"})
    assert (a2c_row["env"], ppo_row["env"]) == ("X, A2C", "X, PPO")
    assert a2c_row["best"]["arm"] == "hybrid_dual_utd4"  # not the better PPO arm
    assert ppo_row["base_arm"] == "ppo" and ppo_row["best"]["arm"] == ppo_row["paper"]["arm"] == "hybrid_dual_ppo"
    assert ppo_row["faster"] is True and ppo_row["oracle"] is None and ppo_row["as_good_as_true"] is None
