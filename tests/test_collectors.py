"""AtariCollector against TorchRL's Collector, feature reuse, devices."""

import pytest
import torch

pytest.importorskip("ale_py")

from torchrl.collectors import Collector  # noqa: E402
from torchrl.envs import RewardSum, TransformedEnv  # noqa: E402
from torchrl.envs.utils import ExplorationType  # noqa: E402

from torchrl_hybrid.collectors import AtariCollector  # noqa: E402
from torchrl_hybrid.envs.atari import AtariEnv  # noqa: E402
from torchrl_hybrid.families.atari import atari_config, build_atari, load_expert, train_atari  # noqa: E402
from torchrl_hybrid.modules import make_atari_actor_critic  # noqa: E402
from torchrl_hybrid.utils.device import resolve_device  # noqa: E402

cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
EXACT = (
    "observation",
    "action",
    ("next", "observation"),
    ("next", "reward"),
    ("next", "score"),
    ("next", "episode_score"),
    ("next", "done"),
    ("next", "terminated"),
    ("next", "truncated"),
    ("next", "lives"),
)


def _reference_batches(policy, game, n, steps, batches, seed, max_frames):
    env = TransformedEnv(
        AtariEnv(game, n, seed=seed, num_threads=1, max_episode_frames=max_frames),
        RewardSum(in_keys=["score"], out_keys=["episode_score"]),
    )
    ref = Collector(
        env,
        policy,
        frames_per_batch=n * steps,
        total_frames=n * steps * batches,
        auto_register_policy_transforms=False,
        exploration_type=ExplorationType.DETERMINISTIC,
    )
    out = [b.clone() for b in ref]
    ref.shutdown()
    return out


@pytest.mark.parametrize("groups", [1, 2, 4])
def test_atari_collector_gives_torchrl_collectors_batches(groups):
    # greedy play, episodes truncated every 50 steps so that batches cross episode ends
    torch.manual_seed(0)
    *_, policy = make_atari_actor_critic(4)
    ref = _reference_batches(policy, "Breakout", 4, 40, 4, seed=3, max_frames=200)
    envs = AtariCollector.make_envs("Breakout", 4, groups=groups, seed=3, num_threads=1, max_episode_frames=200)
    ours = list(
        AtariCollector(
            envs, policy, frames_per_batch=160, total_frames=640, exploration_type=ExplorationType.DETERMINISTIC
        )
    )
    assert len(ours) == len(ref) == 4
    assert sum(int(b["next", "done"].sum()) for b in ours) >= 8
    for a, b in zip(ref, ours):
        assert b.shape == a.shape == (4, 40)
        for k in EXACT:
            assert torch.equal(a[k], b[k]), k
        # log-probs and values: the same network on the same frames; with several
        # groups the CNN runs on smaller batches, which may round differently
        for k in ("action_log_prob", "state_value"):
            assert torch.allclose(a[k], b[k], atol=1e-5), k
            if groups == 1:
                assert torch.equal(a[k], b[k]), k


def test_sampled_actions_come_from_the_current_policy():
    torch.manual_seed(0)
    actor, critic, _, policy = make_atari_actor_critic(4)
    envs = AtariCollector.make_envs("Breakout", 4, groups=2, seed=1, num_threads=1)
    batch = next(iter(AtariCollector(envs, policy, frames_per_batch=80)))
    with torch.no_grad():
        dist = actor.get_dist(batch.select("observation").clone())
        value = critic(batch.select("observation").clone())["state_value"]
    assert torch.allclose(dist.log_prob(batch["action"]), batch["action_log_prob"], atol=1e-5)
    assert torch.allclose(value, batch["state_value"], atol=1e-5)
    assert batch["action"].unique().numel() > 1  # sampled, not greedy


def _loss_and_grads(run, batch, clear_cache):
    if clear_cache:
        run.encoder._cache = None
    run.loss.zero_grad()
    out = run.loss(batch)
    sum(v for k, v in out.items() if k.startswith("loss_")).backward()
    return (
        {k: v.detach().clone() for k, v in out.items()},
        [p.grad.clone() if p.grad is not None else None for p in run.loss.parameters()],
    )


@pytest.mark.parametrize("variant", ["a2c", "hybrid_dual"])
def test_kept_collection_features_give_the_plain_loss_and_gradients(tmp_path, variant, pong_demo_dir):
    cfg = {
        "variant": variant,
        "total_frames": 4 * 160,
        "out_dir": str(tmp_path),
        "device": "cpu",
        "env": {"game": "Pong", "num_envs": 8, "num_threads": 1},
        "loss": {"bc_start_frames": 0},
        "logger": {"progress_bar": False, "checkpoint": False, "backend": "none"},
    }
    if variant != "a2c":
        cfg["demo"] = {"path": str(pong_demo_dir)}
    run = build_atari(atari_config(cfg))
    assert run.trainer.collector.keep_features
    calls = []
    forward = run.encoder._forward
    run.encoder._forward = lambda x: (calls.append(x.shape[:-3].numel()), forward(x))[1]
    batch = run.trainer._process_optim_batch_hook(run.trainer._process_batch_hook(next(iter(run.trainer.collector))))
    calls.clear()
    kept, kept_grads = _loss_and_grads(run, batch, clear_cache=False)
    # the 40 observations of the batch were not encoded again
    assert 40 not in calls
    plain, plain_grads = _loss_and_grads(run, batch, clear_cache=True)
    assert 40 in calls
    for k in plain.keys():
        assert torch.allclose(kept[k], plain[k], rtol=1e-5, atol=1e-7), k
    for a, b in zip(kept_grads, plain_grads):
        assert (a is None) == (b is None)
        if a is not None:
            assert torch.allclose(a, b, rtol=1e-4, atol=1e-7)
    run.trainer.collector.shutdown()


@pytest.fixture(scope="module")
def pong_demo_dir(tmp_path_factory):
    from torchrl_hybrid.families.atari import record_demos

    tmp = tmp_path_factory.mktemp("pong_demos")
    train_atari(
        atari_config(
            {
                "variant": "a2c",
                "total_frames": 4 * 80,
                "out_dir": str(tmp / "expert"),
                "device": "cpu",
                "env": {"num_envs": 8, "num_threads": 1},
                "logger": {"progress_bar": False, "checkpoint": False, "backend": "none"},
            }
        )
    )
    record_demos(
        tmp / "expert" / "model.pt",
        tmp / "demos",
        num_trajectories=2,
        num_envs=2,
        max_steps=20,
        progress=False,
        device="cpu",
    )
    return tmp / "demos"


def test_more_envs_than_the_paper_and_env_groups(tmp_path):
    s = train_atari(
        atari_config(
            {
                "variant": "a2c",
                "total_frames": 4 * 32 * 5 * 2,
                "out_dir": str(tmp_path),
                "device": "cpu",
                "env": {"game": "Pong", "num_envs": 32, "num_threads": 1},
                "collector": {"env_groups": 2},
                "logger": {"progress_bar": False, "checkpoint": False, "backend": "none"},
            }
        )
    )
    assert s["frames"] == 4 * 32 * 5 * 2


@pytest.mark.parametrize(
    "bad, match",
    [
        ({"collector": {"env_groups": 3}}, "env_groups=3 must divide"),
        ({"collector": {"backend": "slurm"}}, "collector.backend='slurm'"),
        ({"device": "tpu"}, "device='tpu'"),
    ],
)
def test_bad_collector_and_device_settings_are_refused(tmp_path, bad, match):
    with pytest.raises(ValueError, match=match):
        atari_config({"variant": "a2c", "out_dir": str(tmp_path), **bad}).validate()


def test_device_setting():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="sees no CUDA GPU"):
            resolve_device("cuda")


def test_out_of_range_actions_are_refused():
    env = AtariEnv("Pong", 2, num_threads=1)
    env.reset()
    with pytest.raises(ValueError, match="Pong has 6 actions"):
        env.send(torch.tensor([0, 17]))
    env.close()


def _tiny(tmp, device, **kw):
    return atari_config(
        {
            "variant": "a2c",
            "total_frames": 4 * 80,
            "out_dir": str(tmp),
            "device": device,
            "env": {"game": "Pong", "num_envs": 8, "num_threads": 1},
            "logger": {"progress_bar": False, "checkpoint": True, "backend": "none", "log_every_frames": 160},
            **kw,
        }
    )


@cuda
@pytest.mark.parametrize("backend", ["atari", "torchrl"])
def test_cuda_run_and_checkpoints_move_between_devices(tmp_path, backend):
    s = train_atari(_tiny(tmp_path, "cuda", collector={"backend": backend}))
    assert s["frames"] == 320
    actor, _ = load_expert(tmp_path / "model.pt", "cpu")
    assert next(actor.parameters()).device.type == "cpu"
    # a CUDA checkpoint resumes on the CPU, and back
    s = train_atari(_tiny(tmp_path, "cpu", collector={"backend": backend}, total_frames=4 * 160, resume=True))
    assert s["frames"] == 640 and s["resumed_from_frames"] == 320
    s = train_atari(_tiny(tmp_path, "cuda", collector={"backend": backend}, total_frames=4 * 240, resume=True))
    assert s["frames"] == 960


@cuda
def test_cuda_collector_matches_cpu_collector():
    torch.manual_seed(0)
    *_, policy = make_atari_actor_critic(4)
    head = policy.module.policy_head
    with torch.no_grad():  # a clear greedy choice: CPU and CUDA rounding cannot flip it
        head.weight.zero_()
        head.bias.copy_(torch.tensor([0.0, 0.0, 3.0, 0.0]))
    outs = {}
    # cuDNN convolutions default to TF32 on Ampere and later (10-bit mantissa): emulated, it moved a
    # state_value by 7e-5 on reset frames, too close to the tolerance; compare full-precision maths
    tf32 = torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32
    torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = False
    try:
        for dev in ("cpu", "cuda"):
            envs = AtariCollector.make_envs("Breakout", 4, seed=3, num_threads=1)
            col = AtariCollector(
                envs,
                policy.to(dev),
                frames_per_batch=80,
                total_frames=160,
                device=dev,
                exploration_type=ExplorationType.DETERMINISTIC,
            )
            outs[dev] = [b.cpu() for b in col]
    finally:
        torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = tf32
    for a, b in zip(outs["cpu"], outs["cuda"]):
        for k in ("observation", ("next", "observation"), ("next", "done")):
            assert torch.equal(a[k], b[k])
        assert torch.allclose(a["state_value"], b["state_value"], atol=1e-4)


def test_checkpoint_resumes_and_loads_on_cpu(tmp_path):
    s = train_atari(_tiny(tmp_path, "cpu"))
    assert s["frames"] == 320
    actor, ckpt = load_expert(tmp_path / "model.pt", "auto")
    assert ckpt["n_actions"] == 6
    s = train_atari(_tiny(tmp_path, "cpu", total_frames=4 * 160, resume=True))
    assert s["frames"] == 640 and s["resumed_from_frames"] == 320


def test_a_checkpoint_for_another_game_is_refused(tmp_path):
    from torchrl_hybrid.families.atari import evaluate_atari

    train_atari(_tiny(tmp_path, "cpu"))
    actor, ckpt = load_expert(tmp_path / "model.pt")
    with pytest.raises(ValueError, match="the policy has 6 actions but Breakout has 4"):
        evaluate_atari(actor, "Breakout", ckpt["preprocessing"], episodes=1, num_envs=1, max_steps=2)


def test_collector_refuses_a_policy_for_another_game():
    *_, policy = make_atari_actor_critic(6)  # Pong's action count
    with pytest.raises(ValueError, match="the policy has 6 actions but Breakout has 4"):
        AtariCollector(AtariCollector.make_envs("Breakout", 2, num_threads=1), policy, frames_per_batch=2)


def test_files_that_are_not_atari_checkpoints_are_named(tmp_path):
    (tmp_path / "empty.pt").write_bytes(b"")
    (tmp_path / "random.pt").write_bytes(bytes(range(256)) * 4)
    torch.save({"actor": {}, "critic": {}, "config": {"variant": "hybrid_dual"}}, tmp_path / "taxi.pt")
    with pytest.raises(ValueError, match="empty.pt is empty, not a model.pt"):
        load_expert(tmp_path / "empty.pt")
    with pytest.raises(ValueError, match="random.pt is not a model.pt written by train_atari"):
        load_expert(tmp_path / "random.pt")
    with pytest.raises(
        ValueError, match=r"taxi.pt is not an Atari checkpoint: it lacks \['n_actions', 'preprocessing'\]"
    ):
        load_expert(tmp_path / "taxi.pt")


def test_atari_runs_and_demos_do_not_overwrite_results(tmp_path):
    from torchrl_hybrid.families.atari import record_demos

    train_atari(_tiny(tmp_path / "run", "cpu"))
    with pytest.raises(ValueError, match="holds a finished run"):
        train_atari(_tiny(tmp_path / "run", "cpu", seed=1))
    assert train_atari(_tiny(tmp_path / "run", "cpu", seed=1, overwrite=True))["seed"] == 1
    (tmp_path / "demos").mkdir()
    (tmp_path / "demos" / "other.txt").write_text("someone else's")
    with pytest.raises(ValueError, match="already exists and is not empty; pass overwrite=true"):
        record_demos(tmp_path / "run" / "model.pt", tmp_path / "demos", num_trajectories=1, progress=False)
    assert (tmp_path / "demos" / "other.txt").read_text() == "someone else's"
