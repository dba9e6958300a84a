import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from conftest import TEST_DEVICE  # the `device` fixture's value: cpu in CI, cuda under make test-cuda

from torchrl_hybrid.data import save_demos
from torchrl_hybrid.families.gym import GymConfig, config_from_dict, train_gym
from torchrl_hybrid.variants import VARIANTS

ROOT = Path(__file__).resolve().parents[1]


def tiny(tmp_path, **kw) -> GymConfig:
    d = {
        "total_frames": 640,
        "out_dir": str(tmp_path / kw.get("variant", "run")),
        "device": TEST_DEVICE,
        "logger": {
            "log_every_frames": 320,
            "eval_episodes": 8,
            "final_eval_episodes": 8,
            "progress_bar": False,
            "backend": "csv",
        },
    }
    if kw.get("engine") == "batched":
        d["device"] = "cpu"  # the batched engine runs on the CPU only
    for k, v in kw.items():
        if "." in k:
            g, kk = k.split(".")
            d.setdefault(g, {})[kk] = v
        else:
            d[k] = v
    return config_from_dict(d)


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_every_variant_runs_and_writes_its_outputs(tmp_path, variant):
    cfg = tiny(tmp_path, variant=variant)
    summary = train_gym(cfg)
    out = Path(cfg.out_dir)
    for f in ("metrics.csv", "summary.json", "learning_curve.png", "model.pt", "checkpoint"):
        assert (out / f).exists(), f
    rows = list(csv.DictReader((out / "metrics.csv").open()))
    assert len(rows) >= 2 and int(rows[-1]["frames"]) == 640
    assert {"frames", "return_mean", "eval_return"} <= set(rows[0])
    has_idm = VARIANTS[variant].inverse_model is not None
    # one meaning per column: the loss's accuracy on the agent's batch, the accuracy on the demo pairs
    assert ("idm_accuracy" in rows[0]) == ("idm_accuracy_expert" in rows[0]) == has_idm
    s = json.loads((out / "summary.json").read_text())
    assert s["variant"] == variant and s["frames"] == 640 and s["final_eval_episodes"] == 8
    assert s == json.loads(json.dumps(summary))


def test_options_noise_rank_curriculum_and_gym_backend(tmp_path):
    s = train_gym(
        tiny(
            tmp_path,
            rank=1,
            **{
                "demo.eta": 0.5,
                "demo.epsilon": 0.2,
                "demo.rho": "curriculum",
                "demo.form": "trajectories",
                "loss.bc_start_frames": 320,
                "env.backend": "gym",
                "env.num_envs": 4,
                "loss.idm_forward_coeff": 1.0,
                "optim.clip": "per_group",
            },
        )
    )
    assert s["config"]["rank"] == 1 and s["frames"] == 640


def test_hybrid_never_reads_true_expert_actions(tmp_path):
    """Same seed, demos with and without their true actions: identical policy."""
    demos_ok = tmp_path / "ok"
    cfg = tiny(tmp_path, **{"demo.save_path": str(demos_ok)})
    train_gym(cfg)
    from tensordict import TensorDict

    # without the true actions (scrambled ones are refused on load: each (s, a, s') is checked against P)
    demos = TensorDict.load_memmap(demos_ok).clone().exclude("expert_action")
    save_demos(demos, tmp_path / "scrambled")
    s1 = train_gym(tiny(tmp_path, out_dir=str(tmp_path / "a"), **{"demo.path": str(demos_ok)}))
    s2 = train_gym(tiny(tmp_path, out_dir=str(tmp_path / "b"), **{"demo.path": str(tmp_path / "scrambled")}))
    w1 = torch.load(tmp_path / "a" / "model.pt", weights_only=False)["actor"]
    w2 = torch.load(tmp_path / "b" / "model.pt", weights_only=False)["actor"]
    assert all(torch.equal(w1[k], w2[k]) for k in w1)
    assert s1["idm_accuracy_expert"] != s2["idm_accuracy_expert"]  # only the diagnostic sees the key


@pytest.mark.parametrize(
    "kw,match",
    [
        ({"variant": "ppo"}, "unknown variant"),
        ({"rank": 0}, "rank must be"),
        ({"demo.eta": 1.0}, "demo.eta must be in"),
        ({"demo.epsilon": -0.1}, "demo.epsilon must be in"),
        ({"demo.rho": "greedy"}, "demo.rho"),
        ({"total_frames": 10}, "less than one batch"),
        ({"device": "tpu"}, "device='tpu'"),
        ({"seed": "abc"}, "seed='abc' must be an integer"),
        ({"rank": "abc"}, "rank='abc' must be an integer"),
        ({"demo.eta": "abc"}, "demo.eta='abc' must be a number"),
        (
            {"env.env_id": "CartPole-v1", "env.backend": "gym"},
            "demo.rho=visited matches expert pairs to visited discrete",
        ),
        ({"env.env_id": "Blackjack-v1"}, "observations are Tuple"),
        ({"env.env_id": "CliffWalkingSlippery-v1"}, "CliffWalkingSlippery-v1: its transitions are random"),
        (
            {"device": "cuda", "engine": "batched"},
            "engine=batched runs on the CPU only" if torch.cuda.is_available() else "sees no CUDA GPU",
        ),
    ],
)
def test_bad_config_is_refused_with_a_clear_message(tmp_path, kw, match):
    with pytest.raises(ValueError, match=match):
        train_gym(tiny(tmp_path, **kw))


def test_bad_demo_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        train_gym(tiny(tmp_path, **{"demo.path": str(tmp_path / "nope")}))
    from tensordict import TensorDict

    save_demos(
        TensorDict({"observation": torch.rand(4, 3), ("next", "observation"): torch.rand(4, 3)}, [4]), tmp_path / "img"
    )
    with pytest.raises(ValueError, match="observation shape"):
        train_gym(tiny(tmp_path, **{"demo.path": str(tmp_path / "img")}))
    nan = TensorDict({"observation": torch.zeros(4), ("next", "observation"): torch.ones(4)}, [4])
    nan["observation"][2] = float("nan")
    save_demos(nan, tmp_path / "nan")
    with pytest.raises(ValueError, match="NaN"):
        train_gym(tiny(tmp_path, **{"demo.path": str(tmp_path / "nan")}))
    floats = TensorDict({"observation": torch.zeros(4), ("next", "observation"): torch.ones(4)}, [4])
    save_demos(floats, tmp_path / "floats")
    with pytest.raises(ValueError, match="dtype"):
        train_gym(tiny(tmp_path, **{"demo.path": str(tmp_path / "floats")}))
    with pytest.raises(ValueError, match="unknown config key"):
        config_from_dict({"demo": {"etaa": 0.1}})


def test_recipe_command_line(tmp_path):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    cmd = [
        sys.executable,
        str(ROOT / "recipes" / "taxi.py"),
        f"out_dir={tmp_path}/cli",
        "total_frames=320",
        "logger.eval_episodes=4",
        "logger.final_eval_episodes=4",
        "logger.progress_bar=false",
    ]
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "final greedy return" in res.stdout and "learning_curve.png" in res.stdout
    fast = subprocess.run(
        cmd + ["engine=batched", f"out_dir={tmp_path}/fast"], capture_output=True, text=True, env=env, timeout=300
    )
    assert fast.returncode == 0 and "final greedy return" in fast.stdout, fast.stderr[-2000:]
    assert (tmp_path / "fast" / "metrics.csv").exists()
    bad = subprocess.run(cmd + ["variant=nope"], capture_output=True, text=True, env=env, timeout=300)
    assert bad.returncode == 2 and "unknown variant 'nope'" in bad.stderr


@pytest.mark.slow
def test_hybrid_dual_learns_taxi_with_the_default_budget(tmp_path):
    cfg = tiny(tmp_path, total_frames=GymConfig().total_frames, seed=0)
    cfg.logger.final_eval_episodes = 300
    s = train_gym(cfg)
    assert s["final_return"] >= 7.0
    assert s["idm_accuracy_expert"] >= 0.80


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
@pytest.mark.parametrize("variant", ["hybrid_dual", "il"])
def test_taxi_trains_on_cuda_and_its_model_loads_on_the_cpu(tmp_path, variant):
    s = train_gym(tiny(tmp_path, variant=variant, device="cuda"))
    assert s["frames"] == 640
    state = torch.load(tmp_path / variant / "model.pt", map_location="cpu", weights_only=False)["actor"]
    assert all(v.device.type == "cpu" for v in state.values())


def test_taxi_runs_with_an_explicit_cpu_device(tmp_path):
    s = train_gym(tiny(tmp_path, variant="hybrid_dual", device="cpu", **{"demo.rho": "visited"}))
    assert s["frames"] == 640 and s["config"]["device"] == "cpu"


def test_demos_with_impossible_transitions_are_refused(tmp_path, taxi):
    from torchrl_hybrid.data import tabular_state_pairs

    model, policy, _ = taxi
    demos = tabular_state_pairs(model, policy)
    save_demos(demos, tmp_path / "ok")
    assert (
        train_gym(tiny(tmp_path, out_dir=str(tmp_path / "a"), **{"demo.path": str(tmp_path / "ok")}))["frames"] == 640
    )
    shuffled = demos.clone()
    shuffled["next", "observation"] = shuffled["next", "observation"][torch.randperm(len(demos))]
    save_demos(shuffled, tmp_path / "shuffled")
    with pytest.raises(ValueError, match=r"pairs are not transitions of Taxi-v4 under any action"):
        train_gym(tiny(tmp_path, out_dir=str(tmp_path / "b"), **{"demo.path": str(tmp_path / "shuffled")}))


def test_robust_bc_options_run_in_the_pipeline(tmp_path):
    s = train_gym(
        tiny(
            tmp_path,
            **{
                "loss.bc_labels": "soft",
                "loss.bc_confidence": 0.3,
                "loss.bc_entropy_floor": 0.5,
                "loss.bc_ready_accuracy": 0.2,
            },
        )
    )
    assert s["frames"] == 640
    import csv

    rows = list(csv.DictReader((tmp_path / "run" / "metrics.csv").open()))
    assert "bc_kept" in rows[-1] and "bc_policy_entropy" in rows[-1]
    with pytest.raises(ValueError, match=r"loss.bc_labels must be one of \('argmax', 'soft'\), got 'hard'"):
        train_gym(tiny(tmp_path / "x", **{"loss.bc_labels": "hard"}))
    assert not (tmp_path / "x").exists()  # refused before anything is written
    # the readiness switch with annealing: on once ready, then falling to 0 over 320 frames
    s = train_gym(tiny(tmp_path / "y", **{"loss.bc_anneal_frames": 320, "loss.bc_ready_accuracy": 0.01}))
    rows = list(csv.DictReader((tmp_path / "y" / "run" / "metrics.csv").open()))
    assert s["frames"] == 640 and float(rows[-1]["loss_bc"]) == 0.0 and float(rows[1]["loss_bc"]) != 0.0
    # annealing: the BC weight in the log falls from bc_coeff at the switch-on to 0 by the end
    s = train_gym(tiny(tmp_path / "z", **{"loss.bc_start_frames": 64, "loss.bc_anneal_frames": 320}))
    rows = list(csv.DictReader((tmp_path / "z" / "run" / "metrics.csv").open()))
    assert s["frames"] == 640 and float(rows[-1]["loss_bc"]) == 0.0 and float(rows[1]["loss_bc"]) != 0.0


def test_frozenlake_8x8_through_env_kwargs_with_its_own_optimal_return(tmp_path):
    kw = {
        "env.env_id": "FrozenLake-v1",
        "env.kwargs": {"map_name": "8x8", "is_slippery": False},
        "env.max_episode_steps": 100,
    }
    s = train_gym(tiny(tmp_path, **kw))
    assert s["optimal_return"] == 1.0 and s["frames"] == 640  # the expert's own evaluation, not assumed
    assert s["config"]["env"]["kwargs"] == {"map_name": "8x8", "is_slippery": False}
    with pytest.raises(ValueError, match="does not end an episode.*expert_gamma"):
        train_gym(tiny(tmp_path, out_dir=str(tmp_path / "g1"), **kw, **{"demo.expert_gamma": 1.0}))
    with pytest.raises(ValueError, match="random"):  # slippery: random transitions, refused before training
        train_gym(
            tiny(
                tmp_path,
                out_dir=str(tmp_path / "slip"),
                **{**kw, "env.kwargs": {"map_name": "8x8", "is_slippery": True}},
            )
        )


def test_vector_observations_cartpole_expert_checkpoint_demos_and_hybrid(tmp_path):
    """CartPole (no table P): an A2C run is the expert, its checkpoint is played to record
    the state-only demos, and the hybrid agent trains on them with MLP encoders."""
    cp = {
        "env.env_id": "CartPole-v1",
        "env.max_episode_steps": 200,
        "demo.rho": "uniform",
        "demo.form": "trajectories",
        "demo.num_trajectories": 4,
        "loss.n_steps": 5,
        "d_state": 16,
        "d": 16,
        "encoder.hidden": 16,
    }
    expert = train_gym(tiny(tmp_path, variant="a2c", out_dir=str(tmp_path / "expert"), **cp))
    assert expert["optimal_return"] is None and expert["idm_accuracy_expert"] is None
    ckpt = str(tmp_path / "expert" / "model.pt")
    s = train_gym(
        tiny(
            tmp_path,
            out_dir=str(tmp_path / "hybrid"),
            **{**cp, "demo.expert": ckpt, "demo.save_path": str(tmp_path / "demos")},
        )
    )
    # the optimum is the expert's own greedy return on the same final episodes, never assumed
    assert s["optimal_return"] == pytest.approx(expert["final_return"])
    assert 0.0 <= s["idm_accuracy_expert"] <= 1.0 and s["frames"] == 640
    rows = list(csv.DictReader((tmp_path / "hybrid" / "metrics.csv").open()))
    assert {"idm_accuracy", "idm_accuracy_expert", "loss_bc"} <= set(rows[0])
    # recorded demos: whole expert episodes, pairs within them, true actions kept for diagnostics only
    from torchrl_hybrid.data import load_demos

    demos, meta = load_demos(tmp_path / "demos")
    assert meta["env_id"] == "CartPole-v1" and len(meta["returns"]) == 4
    assert demos["observation"].shape[1:] == (4,) and int(demos["trajectory"].max()) == 3
    assert demos["expert_action"].dtype == torch.int64
    # the saved demos replace the expert
    s2 = train_gym(tiny(tmp_path, out_dir=str(tmp_path / "from_file"), **{**cp, "demo.path": str(tmp_path / "demos")}))
    assert s2["optimal_return"] is None and s2["frames"] == 640


@pytest.mark.parametrize(
    "kw,match",
    [
        ({}, "no built-in expert.*demo.expert"),
        ({"demo.rho": "visited", "demo.expert": "x"}, "demo.rho=uniform"),
        ({"demo.eta": 0.5, "demo.expert": "x"}, "table P"),
        ({"demo.expert": "/nope/model.pt"}, "no such checkpoint"),
        ({"env.env_id": "MountainCarContinuous-v0"}, "discrete actions"),
    ],
)
def test_vector_observation_errors_name_the_fix(tmp_path, kw, match):
    cfg = tiny(tmp_path, **{"env.env_id": "CartPole-v1", "env.max_episode_steps": 200, "demo.rho": "uniform", **kw})
    with pytest.raises((ValueError, FileNotFoundError), match=match):
        train_gym(cfg)


def _collected_with_current_weights(kind, tmp_path):
    """Batches from make_collector match the learner's policy, also after its weights
    change: the workers' copies are updated by TorchRL's weight update."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from torchrl_hybrid.envs import make_gym_env
    from torchrl_hybrid.families.gym import make_collector
    from torchrl_hybrid.modules import make_tabular_actor_critic

    cfg = tiny(tmp_path, **{"collector.kind": kind, "collector.workers": 2, "env.num_envs": 4})
    actor, _ = make_tabular_actor_critic(500, 6)
    collector = make_collector(cfg, make_gym_env(num_envs=4), actor, torch.device("cpu"))
    try:
        for i, batch in enumerate(collector):
            assert batch.numel() == cfg.frames_per_batch
            with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
                dist = actor.get_dist(batch.select("observation"))
                assert torch.allclose(dist.log_prob(batch["action"]), batch["action_log_prob"], atol=1e-5), i
                for p in actor.parameters():  # a learner update
                    p.add_(torch.randn_like(p))
            collector.update_policy_weights_()
            if i == 2:
                break
    finally:
        collector.shutdown()


def test_multi_process_collection_uses_the_learners_weights(tmp_path):
    _collected_with_current_weights("multi_sync", tmp_path)
    s = train_gym(
        tiny(tmp_path, out_dir=str(tmp_path / "ms"), **{"collector.kind": "multi_sync", "collector.workers": 2})
    )
    assert s["frames"] == 640


@pytest.mark.parametrize(
    "preset,expert",
    [
        ("mountaincar", None),  # the scripted expert of the preset
        ("acrobot", "torchrl_hybrid.experts.scripted:acrobot_energy"),  # a scripted expert by name
        ("lunarlander", "a2c"),  # an expert checkpoint of this pipeline
    ],
)
def test_every_gym_preset_composes_and_runs_the_hybrid_with_its_expert(tmp_path, preset, expert):
    """Each preset of issue 32's envs, as Hydra composes it, on a tiny budget: the demos are
    recorded from its expert (scripted, named as module:function, or a model.pt) and the
    hybrid trains on them; the expert's own return is measured, not assumed."""
    from pathlib import Path

    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from torchrl_hybrid.configs import register_configs

    register_configs()
    folder = str(Path(__file__).resolve().parents[1] / "recipes" / "config")
    tiny_run = [
        f"out_dir={tmp_path / 'run'}",
        "total_frames=400",
        "env.num_envs=4",
        "demo.num_trajectories=2",
        "logger.log_every_frames=200",
        "logger.eval_episodes=2",
        "logger.final_eval_episodes=2",
        "logger.progress_bar=false",
        f"device={TEST_DEVICE}",
    ]
    if preset == "lunarlander":  # an untrained lander hovers for 1,000 steps in every evaluation episode
        tiny_run.append("env.max_episode_steps=100")
    with initialize_config_dir(config_dir=folder, version_base=None):
        if expert == "a2c":
            cfg = compose(config_name=preset, overrides=tiny_run + ["variant=a2c", f"out_dir={tmp_path / 'expert'}"])
            train_gym(config_from_dict(OmegaConf.to_container(cfg, resolve=True)))
            expert = str(tmp_path / "expert" / "model.pt")
        cfg = compose(config_name=preset, overrides=tiny_run + ([f"demo.expert={expert}"] if expert else []))
    d = OmegaConf.to_container(cfg, resolve=True)
    d.pop("hydra", None)
    s = train_gym(config_from_dict(d))
    batch = 4 * d["loss"]["n_steps"]  # the collector's batches: whole ones, up to one past total_frames
    assert 400 <= s["frames"] < 400 + batch and s["variant"] == "hybrid_dual"
    assert s["optimal_return"] is not None and 0.0 <= s["idm_accuracy_expert"] <= 1.0
    if preset == "mountaincar":
        assert -200 < s["optimal_return"] < -80  # the scripted expert reaches the flag
