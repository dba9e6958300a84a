"""The one run assembly (torchrl_hybrid/trainers/run.py): a new env family plugs in,
resuming across added settings, and library calls that leave process-wide settings alone."""

import json

import pytest
import torch
from conftest import TEST_DEVICE  # the `device` fixture's value: cpu in CI, cuda under make test-cuda

from torchrl_hybrid.families.gym import GymConfig, GymFamily, build_gym, config_from_dict, train_gym
from torchrl_hybrid.trainers.run import EnvFamily, Run, build_run, train_run
from torchrl_hybrid.utils.process import configure_worker


def tiny(out, **top) -> GymConfig:
    d = {
        "total_frames": 640,
        "out_dir": str(out),
        "threads": 1,
        "device": TEST_DEVICE,
        "logger": {"log_every_frames": 320, "eval_episodes": 8, "final_eval_episodes": 8, "progress_bar": False},
    }
    d.update(top)
    return config_from_dict(d)


def test_a_new_env_family_plugs_in_by_overriding_one_step(tmp_path):
    """A user's family changes one step (here: its networks, counted) and gets the rest
    (losses, trainer, demos, metrics, summary, model.pt) from the assembly."""
    built = []

    class CountingFamily(GymFamily):
        def networks(self, cfg, variant, setup):
            nets = super().networks(cfg, variant, setup)
            built.append((setup.n_actions, setup.n_states))
            return nets

    s = train_run(tiny(tmp_path / "run"), CountingFamily())
    assert built == [(6, 500)]
    assert s["frames"] == 640 and s["optimal_return"] is not None
    for f in ("metrics.csv", "summary.json", "model.pt", "learning_curve.png", "config.json"):
        assert (tmp_path / "run" / f).exists(), f
    # the base class says what a family must provide
    with pytest.raises(NotImplementedError):
        build_run(tiny(tmp_path / "bare"), EnvFamily())


def test_a_run_that_fails_to_build_closes_its_envs_and_releases_out_dir(tmp_path):
    opened = []

    class FailingFamily(GymFamily):
        def networks(self, cfg, variant, setup):
            opened.extend([setup.env, setup.eval_env])
            raise RuntimeError("no networks today")

        def collector(self, cfg, setup, policy, device, total_steps):
            raise AssertionError("not reached")

    with pytest.raises(RuntimeError, match="no networks today"):
        build_run(tiny(tmp_path / "run"), FailingFamily())
    assert len(opened) == 2 and all(env.is_closed for env in opened)
    train_run(tiny(tmp_path / "run", total_frames=320), GymFamily())  # out_dir was released


def test_build_taxi_gives_the_run_the_trainer_trains(tmp_path):
    run = build_gym(tiny(tmp_path / "run"))
    assert isinstance(run, Run) and run.inverse_model is not None and run.demos is not None
    run.trainer.train()
    assert run.trainer.collected_frames == 640
    run.lock.close()


def test_resume_takes_a_setting_added_since_the_checkpoint_as_its_default(tmp_path):
    out = tmp_path / "run"
    train_gym(tiny(out))
    saved = json.loads((out / "config.json").read_text())
    # a checkpoint written before these settings existed
    del saved["loss"]["bc_entropy_floor"], saved["optim"]["clip"], saved["mlp_layers"]
    (out / "config.json").write_text(json.dumps(saved))
    s = train_gym(tiny(out, total_frames=1280, resume=True))
    assert s["resumed_from_frames"] == 640 and s["frames"] == 1280
    # a setting that differs from the saved one is still refused
    saved = json.loads((out / "config.json").read_text())
    saved["loss"]["bc_coeff"] = 3.0
    (out / "config.json").write_text(json.dumps(saved))
    with pytest.raises(ValueError, match=r"loss.bc_coeff: 3.0 -> 2.0"):
        train_gym(tiny(out, total_frames=1920, resume=True))


def test_library_calls_leave_the_process_settings_alone(tmp_path):
    before = torch.get_num_threads()
    want = 2 if before != 2 else 3
    torch.set_num_threads(want)
    try:
        train_gym(tiny(tmp_path / "run", threads=1))  # threads is for the recipes, not a library call
        assert torch.get_num_threads() == want
        with pytest.warns(RuntimeWarning, match=r"asks for 1 torch thread\(s\) but runs in the calling process"):
            configure_worker(1)  # not a worker process of run_jobs: nothing changes, but it says so
        assert torch.get_num_threads() == want
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize(
    "name, cls",
    [("taxi", "GymConfig"), ("atari", "AtariConfig"), ("cartpole", "GymConfig"), ("atari_expert", "AtariConfig")],
)
def test_recipe_configs_are_the_dataclass_schemas(name, cls):
    """Each default is written once: the recipes' YAML sets only out_dir (and a preset's
    changes) over the ConfigStore schema, which Hydra checks names and types against."""
    import dataclasses
    from pathlib import Path

    from hydra import compose, initialize_config_dir
    from hydra.errors import ConfigCompositionException
    from omegaconf import OmegaConf
    from omegaconf.errors import ValidationError

    from torchrl_hybrid.configs import register_configs
    from torchrl_hybrid.families import atari
    from torchrl_hybrid.families import gym as taxi

    register_configs()
    schema = {"GymConfig": taxi.GymConfig, "AtariConfig": atari.AtariConfig}[cls]
    folder = str(Path(__file__).resolve().parents[1] / "recipes" / "config")
    with initialize_config_dir(config_dir=folder, version_base=None):
        cfg = compose(config_name=name)
        d = OmegaConf.to_container(cfg, resolve=False)
        d.pop("hydra", None)
        default = dataclasses.asdict(schema())
        changed = {k for k in default if d[k] != default[k]}
        preset = {
            "taxi": {"out_dir"},
            "atari": {"out_dir"},
            "cartpole": {"out_dir", "total_frames", "d_state", "d", "env", "demo", "loss", "optim", "logger"},
            "atari_expert": {"out_dir", "variant", "total_frames", "logger"},
        }[name]
        assert changed == preset
        assert set(d) == set(default)
        with pytest.raises((ConfigCompositionException, ValidationError)):
            compose(config_name=name, overrides=["seed=abc"])
        with pytest.raises(ConfigCompositionException):
            compose(config_name=name, overrides=["loss.nope=1"])


def test_optim_is_torchrls_rmsprop_config_and_every_argument_reaches_the_optimiser(tmp_path):
    from torchrl.trainers.algorithms.configs.utils import RMSpropConfig

    from torchrl_hybrid.trainers.config import OptimConfig

    assert issubclass(OptimConfig, RMSpropConfig)
    cfg = tiny(tmp_path / "run", optim={"lr": 3e-4, "momentum": 0.5, "centered": True})
    run = build_gym(cfg)
    group = run.trainer.optimizer.param_groups[0]
    assert isinstance(run.trainer.optimizer, torch.optim.RMSprop)
    assert (group["lr"], group["momentum"], group["centered"], group["eps"]) == (3e-4, 0.5, True, 1e-5)
    run.collector.shutdown()
    run.lock.close()
    with pytest.raises(ValueError, match="optim._target_='torch.optim.Adam'"):
        tiny(tmp_path / "x", optim={"_target_": "torch.optim.Adam"}).validate()
    from torchrl_hybrid.families.gym_batched import train_taxi_batched

    with pytest.raises(ValueError, match=r"plain RMSprop .*'momentum': 0.5.*engine=torchrl"):
        train_taxi_batched([tiny(tmp_path / "y", optim={"momentum": 0.5})])


def test_configure_process_quiets_torchrl_even_before_torchrl_is_imported():
    import subprocess
    import sys

    code = (
        "from torchrl_hybrid.utils.process import configure_process; configure_process(None); "
        "import torch; from torchrl.data import LazyTensorStorage, ReplayBuffer; "
        "ReplayBuffer(storage=LazyTensorStorage(4)).extend(torch.zeros(2, 1))"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "Initialized LazyTensorStorage" not in r.stdout + r.stderr


@pytest.mark.parametrize("warmup, expected", [(None, 1.0), (0, 1.0), (1280, 0.5)])
def test_lr_warmup_raises_the_rate_linearly_then_holds_it(tmp_path, warmup, expected):
    """optim.warmup_frames: the rate after 640 frames is 640/warmup of its value (capped at 1);
    None without init_from means no warm-up (the authors' schedule)."""
    run = build_gym(tiny(tmp_path / "run", optim={"warmup_frames": warmup}))
    try:
        run.trainer.train()
        lrs = [g["lr"] for g in run.trainer.optimizer.param_groups]
        assert lrs == pytest.approx([run.cfg.optim.lr * expected] * len(lrs))
    finally:
        run.lock.close()
        run.collector.shutdown()
    with pytest.raises(ValueError, match="optim.warmup_frames must be >= 0"):
        build_gym(tiny(tmp_path / "bad", optim={"warmup_frames": -1}))


def test_lr_warmup_hook_scale():
    from torchrl_hybrid.trainers.hooks import LRWarmupHook

    opt = torch.optim.RMSprop([torch.nn.Parameter(torch.zeros(1))], lr=0.1)
    hook = LRWarmupHook(opt, 1000)
    assert [hook.scale(f) for f in (0, 250, 1000, 5000)] == [0.0, 0.25, 1.0, 1.0]
    with pytest.raises(ValueError, match="warmup_frames must be > 0"):
        LRWarmupHook(opt, 0)


def test_taxi_init_from_warm_starts_and_refuses_the_batched_engine(tmp_path):
    first = train_gym(tiny(tmp_path / "first"))
    s = train_gym(tiny(tmp_path / "warm", init_from=str(tmp_path / "first" / "model.pt")))
    assert s["total_frames_seen"] == first["frames"] + s["frames"] == 1280
    with pytest.raises(ValueError, match="init_from needs engine=torchrl"):
        tiny(tmp_path / "b", engine="batched", init_from=str(tmp_path / "first" / "model.pt")).validate()
    other = tiny(
        tmp_path / "fl",
        env={"env_id": "FrozenLake-v1", "kwargs": {"is_slippery": False}},
        init_from=str(tmp_path / "first" / "model.pt"),
    )
    with pytest.raises(ValueError, match=r"other settings for \['env.env_id', 'env.kwargs'\]"):
        train_gym(other)


def _stub_trainer(parts, params, lr=1.0):
    """A trainer with what ClippedOptimizationStepper reads: a loss with forward_parts and an optimiser."""
    from types import SimpleNamespace

    from tensordict import TensorDict

    class Loss:
        tensor_keys = SimpleNamespace(agent="agent", expert="expert")
        inverse_dynamics_loss = bc_loss = None

        def forward_parts(self, td):
            return {k: TensorDict(f(), []) for k, f in parts.items()}

        def __call__(self, td):
            out = TensorDict({}, [])
            for p in self.forward_parts(td).values():
                out.update(p)
            return out

    loss = Loss()
    return SimpleNamespace(loss_module=loss, optimizer=torch.optim.SGD(params, lr=lr), compute_loss=lambda td: loss(td))


def test_per_term_clip_keeps_the_bc_gradient_that_a_global_clip_scales_down():
    """RL gradient 100, BC gradient 1, clip 1: one global clip leaves BC 1/101 of a step of 1;
    clipped apart, each term moves the weight by up to 1 and the BC term keeps its whole step."""
    from tensordict import TensorDict

    from torchrl_hybrid.trainers.trainer import ClippedOptimizationStepper

    moves = {}
    for clip in ("global", "per_term"):
        w = torch.nn.Parameter(torch.zeros(1))
        trainer = _stub_trainer(
            {"rl": lambda w=w: {"loss_objective": 100.0 * w.sum()}, "bc": lambda w=w: {"loss_bc": 1.0 * w.sum()}}, [w]
        )
        out = ClippedOptimizationStepper(1.0, clip=clip).step(trainer, TensorDict({}, []))
        moves[clip] = -float(w.detach())
        if clip == "per_term":
            assert float(out["grad_norm_rl"]) == pytest.approx(100.0) and float(out["grad_norm_bc"]) == pytest.approx(
                1.0
            )
    assert moves["global"] == pytest.approx(1.0, abs=1e-5)  # 101 scaled to 1: BC's share is 1/101
    assert moves["per_term"] == pytest.approx(2.0, abs=1e-5)  # RL clipped to 1, BC's 1 kept


def test_extra_bc_and_inverse_model_updates_per_batch(tmp_path):
    """loss.bc_updates=2, loss.idm_updates=1: the policy's parameters take 1 + 2 optimiser steps per
    batch (the main one, then BC alone twice on fresh expert batches), the inverse model's 1 + 1; the
    RL loss is never repeated."""
    run = build_gym(tiny(tmp_path, **{"loss": {"bc_updates": 2, "idm_updates": 1}}))
    run.trainer.train()
    updates = 640 // run.cfg.frames_per_batch
    opt = run.trainer.optimizer
    actor = {id(p) for p in run.actor.parameters()}
    steps = {
        name: {int(opt.state[p]["step"]) for g in opt.param_groups for p in g["params"] if pick(g, p)}
        for name, pick in (
            ("actor", lambda g, p: id(p) in actor),
            ("critic", lambda g, p: g["name"] == "policy" and id(p) not in actor),
            ("inverse_model", lambda g, p: g["name"] == "inverse_model"),
        )
    }
    run.collector.shutdown()
    run.lock.close()
    assert steps == {"actor": {3 * updates}, "critic": {updates}, "inverse_model": {2 * updates}}
    with pytest.raises(ValueError, match="loss.bc_updates must be >= 0"):
        tiny(tmp_path / "bad", **{"loss": {"bc_updates": -1}}).validate()


def test_ppo_base_runs_epochs_of_minibatches_each_paired_with_expert_pairs(tmp_path):
    """rl=ppo: TorchRL's ClipPPOLoss with GAE; each collected batch gets epochs x minibatches
    optimisation steps, each minibatch a quarter of the batch, every transition once per epoch,
    each paired with its own expert batch for BC."""
    from torchrl.objectives import ClipPPOLoss

    cfg = tiny(tmp_path, rl="ppo", ppo={"epochs": 2, "minibatches": 4})
    run = build_gym(cfg)
    assert isinstance(run.loss.rl_loss, ClipPPOLoss) and run.trainer.optim_steps_per_batch == 8
    seen = []
    run.trainer.register_op("process_optim_batch", lambda td: seen.append(td) or td)  # after the expert pairing
    run.trainer.train()
    run.collector.shutdown()
    run.lock.close()
    batch = cfg.frames_per_batch
    assert len(seen) == 8 * (640 // batch)
    assert all(td["agent"].shape == (batch // 4,) and "advantage" in td["agent"].keys() for td in seen)
    assert all("observation" in td["expert"].keys() for td in seen)
    first_epoch = torch.cat([td["agent", "observation"] for td in seen[:4]])
    assert first_epoch.shape == (batch,)
    rows = run.metrics.rows
    assert {"clip_fraction", "loss_bc", "loss_inverse", "kl_approx"} <= set(rows[-1])
    with pytest.raises(ValueError, match="ppo.minibatches=5 must divide a batch of 32"):
        tiny(tmp_path / "bad", rl="ppo", ppo={"minibatches": 5}).validate()
    with pytest.raises(ValueError, match="rl must be one of"):
        tiny(tmp_path / "bad", rl="sac").validate()
