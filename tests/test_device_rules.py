"""CUDA's device rules, checked without a GPU (torchrl_hybrid.testing.DeviceRuleCheck).

The check itself first: each rule it enforces catches a breach, and what CUDA allows
passes. Then every stage of every env family runs with ``device="cuda"`` under it, on
tiny settings: zero breaches, and the device-to-host syncs per update reported (``-s``
prints them) and bounded.
"""

import json
from pathlib import Path

import pytest
import torch

from torchrl_hybrid.testing import DeviceRuleCheck
from torchrl_hybrid.utils.device import resolve_device

# -- the check catches what CUDA refuses, and lets through what CUDA allows ------------------------


def test_each_rule_catches_its_breach_and_names_the_line():
    with DeviceRuleCheck() as check:
        dev = check.device
        x = torch.ones(3, device=dev)
        _ = x + torch.ones(3)  # a CPU vector meets a device tensor
        torch.zeros(3)[x > 0]  # CPU tensor, device mask
        torch.randint(3, (2,), device=dev, generator=torch.Generator())  # CPU generator, device op
        x.numpy()  # numpy() of a device tensor
    rules = [b.rule for b in check.breaches]
    assert rules == [
        "mixed devices",
        "CPU tensor indexed with a device index",
        "CPU torch.Generator on a device op",
        "numpy() of a device tensor",
    ]
    assert all(b.where.startswith("tests/test_device_rules.py:") for b in check.breaches)
    with DeviceRuleCheck(raise_on_breach=True) as check, pytest.raises(RuntimeError, match="mixed devices"):
        torch.ones(2, device=check.device) * torch.ones(2)


def test_what_cuda_allows_is_no_breach_and_syncs_are_counted():
    with DeviceRuleCheck() as check:
        dev = check.device
        x = torch.arange(6.0, device=dev)
        y = x * torch.tensor(2.0)  # 0-dim CPU tensors are scalars on CUDA too
        z = x[torch.tensor([0, 2])]  # a device tensor indexed with CPU indices
        w = x.cpu() + torch.ones(6)  # an explicit copy: legal, and a sync
        lin = torch.nn.Linear(6, 2).to(dev)
        lin(x).sum().backward()
        assert lin.weight.grad.device.type == dev.type and y.device.type == z.device.type == dev.type
        float(x.sum()), bool(x.any()), x[x > 2]  # three syncs
    assert check.breaches == [] and w.device.type == "cpu"
    assert check.total_syncs() == 4, check.report()


def test_cuda_resolves_to_the_stand_in_only_inside_a_check():
    with DeviceRuleCheck() as check:
        assert resolve_device("cuda") == check.device
        assert resolve_device("auto") == check.device  # as on a GPU machine
        assert resolve_device("auto", small_model=True).type == "cpu"  # tiny networks stay on the CPU
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="sees no CUDA GPU"):
            resolve_device("cuda")


# -- every stage of every family, device=cuda, under the check ---------------------------------


def _updates(out: Path) -> int:
    return int(json.loads((out / "summary.json").read_text())["config"]["total_frames"])


# syncs that do not come once per update: the learning curve's evaluation episodes and checkpoint
# writes (both once per row or checkpoint), printed in the report but not in the bound
PER_ROW = ("trainers/evaluation.py", "tensordict/memmap.py", "experts/recording.py")


def _assert_clean(check: DeviceRuleCheck, updates: int, max_syncs_per_update: float, what: str) -> None:
    print(f"\n{what}: {updates} updates\n{check.report()}")
    assert not check.breaches, check.report()
    training = sum(n for where, n in check.syncs.items() if not any(p in where for p in PER_ROW))
    per_update = training / updates
    print(f"{per_update:.1f} syncs per update (not counting evaluation, recording and checkpoints)")
    assert per_update <= max_syncs_per_update, f"{what}: {per_update:.1f} syncs per update\n{check.report()}"


def _taxi(tmp_path, **kw):
    from torchrl_hybrid.families.gym import config_from_dict

    d = {
        "total_frames": 640,
        "out_dir": str(tmp_path),
        "device": "cuda",
        "logger": {"log_every_frames": 320, "eval_episodes": 4, "final_eval_episodes": 4, "progress_bar": False},
    }
    for k, v in kw.items():
        if isinstance(v, dict):
            d.setdefault(k, {}).update(v)
        else:
            d[k] = v
    return config_from_dict(d)


@pytest.mark.parametrize("rho", ["visited", "uniform", "curriculum"])
def test_taxi_hybrid_keeps_the_device_rules(tmp_path, rho):
    from torchrl_hybrid.families.gym import train_gym

    with DeviceRuleCheck() as check:
        s = train_gym(_taxi(tmp_path, demo={"rho": rho}))
    assert s["frames"] == 640
    updates = 640 // s["config"]["env"]["num_envs"] // s["config"]["loss"]["n_steps"]
    # per update: TorchRL's collector copies every env step to the host (the envs are on the CPU)
    _assert_clean(check, updates, 40, f"Taxi hybrid_dual, rho={rho}")


def test_taxi_resume_and_every_variant_keep_the_device_rules(tmp_path):
    from torchrl_hybrid.families.gym import train_gym
    from torchrl_hybrid.variants import VARIANTS

    with DeviceRuleCheck() as check:
        for v in VARIANTS:
            train_gym(_taxi(tmp_path / v, variant=v, total_frames=320))
        s = train_gym(_taxi(tmp_path / "hybrid_dual", variant="hybrid_dual", total_frames=640, resume=True))
    assert s["resumed_from_frames"] == 320 and s["frames"] == 640
    _assert_clean(check, 7 * 320 // 32, 60, "Taxi, every variant, then a resume")


def test_cartpole_hybrid_keeps_the_device_rules(tmp_path):
    from torchrl_hybrid.families.gym import train_gym

    cart = {
        "env": {"env_id": "CartPole-v1", "num_envs": 4, "max_episode_steps": 50},
        "loss": {"n_steps": 5},
        "d_state": 16,
        "d": 16,
        "encoder": {"hidden": 16},
        "logger": {"log_every_frames": 200, "eval_episodes": 2, "final_eval_episodes": 2, "progress_bar": False},
    }
    demo = {"rho": "uniform", "form": "trajectories", "num_trajectories": 2}
    train_gym(_taxi(tmp_path / "expert", variant="a2c", total_frames=400, device="cpu", demo=demo, **cart))
    with DeviceRuleCheck() as check:
        s = train_gym(
            _taxi(
                tmp_path / "hybrid",
                variant="hybrid_dual",
                total_frames=400,
                demo={**demo, "expert": str(tmp_path / "expert" / "model.pt")},
                **cart,
            )
        )
    assert s["frames"] == 400
    _assert_clean(check, 400 // 20, 40, "CartPole hybrid_dual")


# -- Atari --------------------------------------------------------------------------------------


def _atari(tmp, **kw):
    from test_atari import tiny  # the Atari tests' tiny settings, here with device=cuda by default

    return tiny(tmp, **{"device": "cuda", **kw})


@pytest.fixture(scope="module")
def atari_demos(tmp_path_factory):
    pytest.importorskip("ale_py")
    from torchrl_hybrid.families.atari import record_demos, train_atari

    tmp = tmp_path_factory.mktemp("standin_pong")
    train_atari(_atari(tmp / "expert", variant="a2c", device="cpu"))
    record_demos(
        tmp / "expert" / "model.pt",
        tmp / "demos",
        num_trajectories=3,
        num_envs=2,
        max_steps=20,
        progress=False,
        device="cpu",
    )
    return tmp


ATARI_UPDATES = 256 // 4 // (2 * 4)  # total_frames / frame skip / frames per batch


@pytest.mark.parametrize(
    "variant,kw",
    [
        ("a2c", {}),
        ("hybrid_dual", {}),
        ("hybrid_mlp", {}),
        ("bc_dual", {}),
        ("hybrid_dual", {"idm_encoder": "own"}),
        ("hybrid_dual", {"collector": {"backend": "torchrl"}}),
        ("hybrid_dual", {"collector": {"backend": "atari", "keep_features": False}}),
        ("hybrid_dual", {"demo": {"curriculum": False}}),
    ],
)
def test_atari_variants_keep_the_device_rules(atari_demos, tmp_path, variant, kw):
    from torchrl_hybrid.families.atari import train_atari

    if variant != "a2c":
        kw = {
            **kw,
            "demo": {"path": str(atari_demos / "demos"), "curriculum_frames_per_step": 64, **kw.get("demo", {})},
        }
    with DeviceRuleCheck() as check:
        s = train_atari(_atari(tmp_path, variant=variant, **kw))
    assert s["frames"] == 256
    _assert_clean(check, ATARI_UPDATES, 30, f"Atari {variant} {kw}")


def test_atari_resume_recording_and_evaluation_keep_the_device_rules(atari_demos, tmp_path):
    from torchrl_hybrid.experts import load_expert
    from torchrl_hybrid.families.atari import evaluate_atari, record_demos, train_atari

    demo = {"path": str(atari_demos / "demos")}
    with DeviceRuleCheck() as check:
        train_atari(_atari(tmp_path / "run", variant="hybrid_dual", demo=demo, logger={"checkpoint": True}))
        s = train_atari(
            _atari(
                tmp_path / "run",
                variant="hybrid_dual",
                demo=demo,
                total_frames=512,
                resume=True,
                logger={"checkpoint": True},
            )
        )
        assert s["resumed_from_frames"] == 256 and s["frames"] == 512
        meta = record_demos(
            tmp_path / "run" / "model.pt",
            tmp_path / "demos",
            num_trajectories=2,
            num_envs=2,
            max_steps=8,
            progress=False,
            device="cuda",
        )
        actor, ckpt = load_expert(tmp_path / "run" / "model.pt", "cuda")
        ev = evaluate_atari(actor, "Pong", ckpt["preprocessing"], episodes=2, num_envs=2, max_steps=16, num_threads=1)
    assert meta["num_trajectories"] == 2 and ev["episodes"] >= 0
    _assert_clean(check, 2 * ATARI_UPDATES, 60, "Atari resume, record_demos, evaluate_atari")


def test_atari_worker_collectors_keep_the_device_rules_and_the_learners_weights(atari_demos, tmp_path):
    """multi_sync workers run a CPU copy of the learner's policy; after every update the
    learner's weights reach them, so each batch's log-probabilities are the learner's own."""
    from tensordict import TensorDict

    from torchrl_hybrid.families.atari import build_atari
    from torchrl_hybrid.trainers.run import finish_run

    seen = []
    with DeviceRuleCheck() as check:
        run = build_atari(
            _atari(
                tmp_path,
                variant="hybrid_dual",
                collector={"backend": "multi_sync", "workers": 2},
                demo={"path": str(atari_demos / "demos")},
            )
        )

        def same_policy(batch):
            with torch.no_grad():
                flat = batch.reshape(-1)
                dist = run.actor.get_dist(TensorDict({"observation": flat["observation"]}, flat.shape))
                seen.append(float((dist.log_prob(flat["action"]) - flat["action_log_prob"]).abs().max()))
            return batch

        run.trainer.register_op("batch_process", same_policy)
        run.trainer.train()
        s = finish_run(run)
    assert s["frames"] == 256
    assert len(seen) == ATARI_UPDATES and max(seen) < 1e-5, seen
    _assert_clean(check, ATARI_UPDATES, 30, "Atari hybrid_dual, multi_sync workers")


# -- each finding of the CUDA review, with its own test ----------------------------------------


def test_feature_reuse_creates_its_index_tensors_on_the_frames_device():
    """The crash: AtariEncoder._shifted indexed CPU tensors with a device mask."""
    from torchrl_hybrid.modules import AtariEncoder

    enc = AtariEncoder()
    frames = torch.randint(0, 255, (3, 5, 4, 84, 84), dtype=torch.uint8)
    frames[:, 2] = frames[:, 1]  # some next frames equal the following step's frames
    nxt = torch.cat([frames[:, 1:], frames[:, :1]], 1).contiguous()
    ref = enc(nxt).detach()
    enc._cache = None  # its graph holds the weights, which the stand-in's .to() swaps in place
    with DeviceRuleCheck() as check:
        enc.to(check.device)
        f, n = frames.to(check.device), nxt.to(check.device)
        enc(f)  # cached for the shifted call
        out = enc(n)
    assert not check.breaches, check.report()
    assert torch.allclose(out.elem if hasattr(out, "elem") else out, ref, atol=1e-6)


def test_ray_workers_run_their_policy_on_the_cpu_unless_they_ask_for_gpus(monkeypatch):
    import torchrl.collectors.distributed as distributed

    from torchrl_hybrid.collectors import workers

    seen = {}

    class FakeRayCollector:
        def __init__(self, env_fns, policy, **kw):
            seen.update(kw, policy=policy)

    monkeypatch.setattr(distributed, "RayCollector", FakeRayCollector)
    monkeypatch.setattr("torchrl_hybrid.utils.launch.init_ray", lambda *a, **k: False)
    policy = torch.nn.Linear(2, 2)
    workers.make_worker_collector("ray", [lambda: None] * 2, policy, frames_per_batch=4, total_frames=8)
    assert (seen["env_device"], seen["policy_device"], seen["storing_device"]) == ("cpu", "cpu", "cpu")
    assert seen["remote_configs"] == {"num_cpus": 1} and seen["policy"] is policy
    workers.make_worker_collector(
        "ray", [lambda: None] * 2, policy, frames_per_batch=4, total_frames=8, worker_gpus=0.5
    )
    assert seen["remote_configs"] == {"num_cpus": 1, "num_gpus": 0.5} and seen["policy_device"] == "cuda"
    with pytest.raises(ValueError, match="worker_gpus=0.5 is a Ray setting"):
        workers.worker_devices("multi_sync", 0.5)
    with DeviceRuleCheck() as check:  # a learner on a GPU hands the workers a CPU copy
        on_dev = torch.nn.Linear(2, 2).to(check.device)
        workers.make_worker_collector("ray", [lambda: None] * 2, on_dev, frames_per_batch=4, total_frames=8)
        assert seen["policy"] is not on_dev and seen["policy"].weight.device.type == "cpu"
        weights = workers.worker_weights_getter(on_dev)()
        assert weights["weight"].device.type == "cpu" and torch.equal(weights["weight"], on_dev.weight.elem)


def test_random_state_includes_every_cuda_generator(monkeypatch):
    from torchrl_hybrid.trainers.hooks import random_state, set_random_state

    assert "cuda_rng" not in random_state() or torch.cuda.is_initialized()
    gens = [torch.arange(4, dtype=torch.uint8), torch.arange(4, 8, dtype=torch.uint8)]
    restored = []
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "is_initialized", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    monkeypatch.setattr(torch.cuda, "get_rng_state_all", lambda: gens)
    monkeypatch.setattr(torch.cuda, "set_rng_state_all", lambda states: restored.extend(states))
    state = random_state()
    assert torch.equal(state["cuda_rng"], torch.stack(gens))
    torch.manual_seed(123)
    set_random_state(state)
    assert [t.tolist() for t in restored] == [g.tolist() for g in gens]
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    with pytest.warns(UserWarning, match="random state of 2 CUDA device"):
        set_random_state(state)


def test_an_atari_checkpoint_restores_the_random_state(tmp_path):
    pytest.importorskip("ale_py")
    from torchrl_hybrid.families.atari import build_atari
    from torchrl_hybrid.trainers.run import close_run

    run = build_atari(_atari(tmp_path, variant="a2c", device="cpu", logger={"checkpoint": True}))
    run.trainer.train()
    state = torch.get_rng_state()
    run.trainer.save_trainer(force_save=True)
    close_run(run)
    torch.manual_seed(999)  # what build_run does on resume: the seed's stream, until the checkpoint loads
    run = build_atari(
        _atari(tmp_path, variant="a2c", device="cpu", total_frames=512, resume=True, logger={"checkpoint": True})
    )
    close_run(run)
    assert "random_state" in run.trainer._modules
    assert torch.equal(torch.get_rng_state(), state)


class _Spy:
    def __init__(self, storage):
        self.storage, self.whole_reads = storage, 0

    def install(self):
        get = self.storage.get

        def spy(index):
            self.whole_reads += 1
            return get(index)

        self.storage.get = spy


@pytest.mark.parametrize("kind", ["curriculum", "visited"])
def test_expert_samplers_read_one_entry_not_the_whole_buffer(kind):
    from tensordict import TensorDict

    from torchrl_hybrid.data import CurriculumSampler, VisitedStateSampler, make_expert_buffer

    n = 50
    demos = TensorDict(
        {
            "observation": torch.arange(n) % 10,
            "next": {"observation": (torch.arange(n) + 1) % 10},
            "step": torch.arange(n) % 7,
            "trajectory": torch.arange(n) // 7,
        },
        [n],
    )
    sampler = CurriculumSampler(k0=3, frames_per_step=100) if kind == "curriculum" else VisitedStateSampler(10)
    rb = make_expert_buffer(demos, sampler=sampler, batch_size=16)
    spy = _Spy(rb.storage)
    spy.install()
    if kind == "visited":
        sampler.observe(torch.tensor([1, 2, 3, 1]))
    batch = rb.sample()
    assert spy.whole_reads == 1  # the sampled items only, not every stored item for their step / state
    if kind == "curriculum":
        assert bool((batch["step"] < 3).all()) and batch.shape == (16,)
    else:
        assert sorted(batch["observation"].tolist()) == [1, 1, 2, 3]


def test_the_trainer_keeps_no_per_update_log_and_the_curve_reads_the_device_once_per_row(tmp_path):
    from torchrl_hybrid.families.gym import build_gym
    from torchrl_hybrid.trainers.run import finish_run

    run = build_gym(_taxi(tmp_path, device="cpu", total_frames=640, logger={"log_every_frames": 320}))
    run.trainer.train()
    finish_run(run)
    updates = 640 // 32
    assert updates == 20
    rows = run.metrics.rows
    # TorchRL's auto_log_optim_steps kept every update's losses in _log_dict (20 entries a key); now
    # only the progress bar's values of each learning-curve row are there
    assert len(rows) == 3 and all(len(v) <= len(rows) for v in run.trainer._log_dict.values()), {
        k: len(v) for k, v in run.trainer._log_dict.items()
    }
    assert {"loss_objective", "grad_norm", "idm_accuracy"} <= set(rows[-1])
    assert all(isinstance(rows[-1][k], float) for k in ("loss_objective", "grad_norm"))


def test_cuda_graph_compile_modes_see_a_few_padded_batch_sizes():
    """reduce-overhead records one CUDA graph per input shape; feature reuse leaves a
    different number of rows to the CNN at every update, so batches are padded to powers of two."""
    from torchrl_hybrid.modules import AtariEncoder
    from torchrl_hybrid.modules.atari import padded_batch_size

    enc = AtariEncoder()
    shapes = []

    def recording_cnn(x):
        shapes.append(x.shape[0])
        return enc._cnn(x)

    enc.compile_mode, enc._compiled = "reduce-overhead", recording_cnn
    x = torch.randint(0, 255, (40, 4, 84, 84), dtype=torch.uint8)
    for n in (16, 17, 18, 19, 32, 40, 5):
        out = enc(x[:n].clone())
        enc.compile_mode, compiled = "off", enc._compiled
        enc._compiled = None
        ref = enc(x[:n].clone())
        enc.compile_mode, enc._compiled = "reduce-overhead", compiled
        assert torch.allclose(out, ref, atol=1e-5)
    assert set(shapes) == {8, 16, 32, 64} and all(s == padded_batch_size(s) for s in shapes)


@pytest.mark.slow
def test_the_compiled_cnn_runs_and_matches_the_plain_one():
    from torchrl_hybrid.modules import AtariEncoder

    enc = AtariEncoder().compile_cnn("default")
    x = torch.randint(0, 255, (6, 4, 84, 84), dtype=torch.uint8)
    out = enc(x)
    assert enc._compiled is not None
    enc.compile_cnn("off")
    assert torch.allclose(out, enc(x), atol=1e-5)


def test_device_auto_keeps_tabular_and_small_mlp_runs_on_the_cpu(tmp_path):
    from torchrl_hybrid.families.atari import build_atari
    from torchrl_hybrid.families.gym import build_gym
    from torchrl_hybrid.trainers.run import close_run

    with DeviceRuleCheck() as check:  # a machine with a GPU
        run = build_gym(_taxi(tmp_path / "taxi", device="auto"))
        close_run(run)
        assert run.device.type == "cpu" and next(run.actor.parameters()).device.type == "cpu"
        if pytest.importorskip("ale_py"):
            run = build_atari(_atari(tmp_path / "atari", variant="a2c", device="auto"))
            close_run(run)
            assert run.device == check.device


def test_a_checkpoint_from_before_the_random_state_resumes_with_a_warning(tmp_path, monkeypatch):
    """Checkpoints written before RandomStateHook existed lack only that component: they
    resume (not bit-exactly, said in a warning)."""
    import torchrl_hybrid.families.gym as taxi

    cart = {
        "env": {"env_id": "CartPole-v1", "num_envs": 4, "max_episode_steps": 50},
        "loss": {"n_steps": 5},
        "d_state": 16,
        "d": 16,
        "encoder": {"hidden": 16},
        "variant": "a2c",
        "device": "cpu",
        "demo": {"rho": "uniform"},
    }
    with monkeypatch.context() as m:  # a checkpoint as the code before this hook wrote it
        m.setattr(taxi.GymFamily, "register_late_hooks", lambda self, run: None)
        taxi.train_gym(_taxi(tmp_path, total_frames=400, **cart))
    with pytest.warns(UserWarning, match="written before checkpoints held the random state"):
        s = taxi.train_gym(_taxi(tmp_path, total_frames=800, resume=True, **cart))
    assert s["resumed_from_frames"] == 400 and s["frames"] == 800


@pytest.mark.parametrize(
    "kw",
    [
        {
            "variant": "hybrid_dual",
            "optim": {"clip": "per_term"},
            "demo": {"rho": "uniform"},
            "loss": {"bc_prior_floor": 0.05, "bc_updates": 2, "idm_updates": 1, "explore_envs": 4},
        },
        {"variant": "hybrid_true", "rl": "ppo", "loss": {"bc_updates": 1, "explore_envs": 4}},
    ],
)
def test_the_balance_label_and_ppo_options_keep_the_device_rules(tmp_path, kw):
    from torchrl_hybrid.families.gym import train_gym

    with DeviceRuleCheck() as check:
        s = train_gym(_taxi(tmp_path, **kw))
    assert s["frames"] == 640
    steps = 640 // 32 * (16 if kw.get("rl") == "ppo" else 1)  # PPO: 4 epochs x 4 minibatches per batch
    _assert_clean(check, steps, 40, f"Taxi {kw} (per optimisation step)")
