import csv

import pytest
import torch

pytest.importorskip("ale_py")

from conftest import TEST_DEVICE  # the `device` fixture's value: cpu in CI, cuda under make test-cuda
from torchrl.collectors import Collector  # noqa: E402
from torchrl.envs.utils import check_env_specs  # noqa: E402

from torchrl_hybrid.envs.atari import ATARI_GAMES, AtariEnv, action_names  # noqa: E402
from torchrl_hybrid.modules import AtariEncoder, DualInverseDynamics, make_atari_actor_critic  # noqa: E402
from torchrl_hybrid.objectives import DualInverseDynamicsLoss  # noqa: E402


def test_encoder_matches_the_paper():
    enc = AtariEncoder()
    convs = [m for m in enc.convs if isinstance(m, torch.nn.Conv2d)]
    assert [(c.out_channels, c.kernel_size[0], c.stride[0]) for c in convs] == [(32, 8, 4), (64, 4, 2), (32, 3, 1)]
    assert enc.fc[0].in_features == 32 * 7 * 7 and enc.out_features == 512
    assert enc(torch.zeros(5, 4, 84, 84, dtype=torch.uint8)).shape == (5, 512)
    with pytest.raises(ValueError, match="frame stacks"):
        enc(torch.zeros(2, 3, 84, 84))


def test_env_specs_preprocessing_and_stack_semantics():
    env = AtariEnv("Pong", 2, num_threads=1)
    check_env_specs(env)
    td = env.rollout(6)
    obs, nxt = td["observation"], td["next", "observation"]
    assert obs.shape == (2, 6, 4, 84, 84) and obs.dtype == torch.uint8
    # frame stacking: each step drops the oldest frame and appends one
    assert torch.equal(obs[:, :, 1:], nxt[:, :, :-1])
    assert torch.equal(obs[:, 1:], nxt[:, :-1])
    assert env.preprocessing["frameskip"] == 4 and env.preprocessing["noop_max"] == 30
    env.close()


def test_final_observation_is_kept_and_reward_is_clipped():
    env = AtariEnv("Breakout", 8, num_threads=1, seed=3)
    td = env.rollout(400, break_when_any_done=False)
    done = td["next", "done"].squeeze(-1)
    assert done.any(), "random Breakout play should lose within 400 steps"
    e, t = [int(i) for i in done.nonzero()[0]]
    assert t + 1 < td.shape[1]
    # the step's next observation is the last frame stack of the old episode,
    # the following root observation the first of the new one
    assert not torch.equal(td["next", "observation"][e, t], td["observation"][e, t + 1])
    # ... and it continues the old episode's stack
    assert torch.equal(td["next", "observation"][e, t, :-1], td["observation"][e, t, 1:])
    r, score = td["next", "reward"], td["next", "score"]
    assert torch.equal(r, score.sign()) and set(r.unique().tolist()) <= {-1.0, 0.0, 1.0}
    assert (td["next", "lives"] >= 0).all()
    env.close()


@pytest.mark.parametrize("game", ATARI_GAMES)
def test_every_paper_game_loads_and_steps(game):
    env = AtariEnv(game, 2, num_threads=1)
    td = env.rollout(3)
    assert td["observation"].shape == (2, 3, 4, 84, 84)
    names = action_names(game)  # one name per action the env takes, in its order
    assert len(names) == env.n_actions and names[0] == "NOOP" and len(set(names)) == len(names)
    env.close()


def test_unknown_game_is_refused():
    with pytest.raises(ValueError, match=r"unknown Atari game 'NotAGame'; ale-py .* has: .*MontezumaRevenge.*Pong"):
        AtariEnv("NotAGame", 1)
    with pytest.raises(ValueError, match=r"unknown Atari game 'NotAGame'; ale-py has: .*Pong"):
        action_names("NotAGame")


def test_shared_encoder_inverse_model_trains_on_collected_atari_transitions():
    env = AtariEnv("Pong", 2, num_threads=1)
    actor, critic, enc, _ = make_atari_actor_critic(env.n_actions)
    idm = DualInverseDynamics(enc, env.n_actions, rank=8)
    assert idm.W_s.in_features == 512 and idm.M.shape == (8, 128, 128)
    batch = next(iter(Collector(env, actor, frames_per_batch=8, total_frames=8)))
    out = DualInverseDynamicsLoss(idm, action_coeff=1.0)(batch)
    sum(v for k, v in out.items() if k.startswith("loss_")).backward()
    assert enc.convs[0].weight.grad is not None  # the shared encoder learns from the inverse model too
    env.close()


# ---------------------------------------------------------------- the pipeline
import json  # noqa: E402
import math  # noqa: E402
import os  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

from torchrl_hybrid.data import CurriculumSampler, load_demos, make_expert_buffer  # noqa: E402
from torchrl_hybrid.families.atari import atari_config, record_demos, train_atari  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TINY = {
    "env": {"num_envs": 2, "num_threads": 1},
    "loss": {"n_steps": 4, "bc_start_frames": 64},
    "logger": {"progress_bar": False, "log_every_frames": 128, "checkpoint": False},
    "total_frames": 256,
}


def tiny(tmp, **kw):
    d = json.loads(json.dumps(TINY))
    for k, v in kw.items():
        if isinstance(v, dict):
            d.setdefault(k, {}).update(v)
        else:
            d[k] = v
    d.setdefault("out_dir", str(tmp))
    d.setdefault("device", TEST_DEVICE)
    return atari_config(d)


@pytest.mark.parametrize("game", ATARI_GAMES)
def test_every_stage_runs_for_every_game(tmp_path, game):
    expert = train_atari(tiny(tmp_path / "expert", variant="a2c", env={"game": game}))
    assert expert["frames"] == 256 and (tmp_path / "expert" / "model.pt").exists()
    meta = record_demos(
        tmp_path / "expert" / "model.pt",
        tmp_path / "demos",
        num_trajectories=2,
        num_envs=2,
        max_steps=12,
        progress=False,
    )
    assert meta["game"] == game and meta["num_trajectories"] == 2 and max(meta["lengths"]) <= 12
    s = train_atari(
        tiny(
            tmp_path / "hybrid",
            variant="hybrid_dual",
            env={"game": game},
            demo={"path": str(tmp_path / "demos"), "curriculum_frames_per_step": 64},
        )
    )
    assert s["frames"] == 256
    assert (tmp_path / "hybrid" / "metrics.csv").read_text().startswith("frames,return_mean")


@pytest.fixture(scope="module")
def pong_demos(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("pong")
    train_atari(tiny(tmp / "expert", variant="a2c"))
    record_demos(
        tmp / "expert" / "model.pt", tmp / "demos", num_trajectories=3, num_envs=2, max_steps=20, progress=False
    )
    return tmp


def test_demo_dataset_round_trip_and_curriculum(pong_demos):
    demos, meta = load_demos(pong_demos / "demos", obs_shape=(4, 84, 84), obs_dtype=torch.uint8)
    assert meta["num_trajectories"] == 3 and demos.batch_size.numel() == sum(meta["lengths"])
    assert demos["observation"].dtype == torch.uint8 and "expert_action" in demos.keys()
    assert int(demos["step"].max()) == max(meta["lengths"]) - 1
    # consecutive pairs of one trajectory chain up; none spans two trajectories
    same = demos["trajectory"][1:] == demos["trajectory"][:-1]
    assert torch.equal(demos["next", "observation"][:-1][same], demos["observation"][1:][same])
    sampler = CurriculumSampler(k0=3, frames_per_step=100)
    buf = make_expert_buffer(demos, sampler=sampler)
    assert int(buf.sample(256)["step"].max()) <= 2
    sampler.update(frames=500)
    assert int(buf.sample(512)["step"].max()) > 2 and "expert_action" not in buf.sample(4).keys()


def test_demo_cut_at_first_point_in_games_without_lives(pong_demos, tmp_path):
    # Pong has no lives: "auto" cuts at the first point lost (negative reward)
    meta = record_demos(
        pong_demos / "expert" / "model.pt",
        tmp_path / "d",
        num_trajectories=2,
        num_envs=2,
        max_steps=400,
        progress=False,
    )
    assert meta["cut"].startswith("first point lost") and "point" in meta["ends"]
    for end, n in zip(meta["ends"], meta["lengths"]):
        assert end in ("point", "max_steps") and (n < 400) == (end == "point")
    meta = record_demos(
        pong_demos / "expert" / "model.pt",
        tmp_path / "e",
        num_trajectories=1,
        num_envs=2,
        max_steps=150,
        cut="episode",
        progress=False,
    )
    assert meta["ends"] == ["max_steps"] and meta["lengths"] == [150]
    with pytest.raises(ValueError, match="cut='lives'"):
        record_demos(pong_demos / "expert" / "model.pt", tmp_path / "f", cut="lives", progress=False)


def test_demo_mismatches_are_refused(pong_demos, tmp_path):
    with pytest.raises(ValueError, match="demos are for 'Pong'"):
        train_atari(
            tiny(tmp_path, variant="hybrid_dual", env={"game": "Breakout"}, demo={"path": str(pong_demos / "demos")})
        )
    with pytest.raises(ValueError, match="preprocessing"):
        train_atari(
            tiny(tmp_path, variant="hybrid_dual", env={"noop_max": 5}, demo={"path": str(pong_demos / "demos")})
        )
    with pytest.raises(ValueError, match="needs expert demos"):
        train_atari(tiny(tmp_path, variant="bc_dual"))
    with pytest.raises(ValueError, match="unknown Atari variant"):
        train_atari(tiny(tmp_path, variant="il"))
    with pytest.raises(FileNotFoundError, match="atari_expert.py"):
        record_demos(tmp_path / "nope.pt", tmp_path / "d", progress=False)


def test_atari_recipes_command_line(tmp_path):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    common = [
        "env.num_envs=2",
        "env.num_threads=1",
        "env.max_episode_frames=400",
        "loss.n_steps=4",
        "total_frames=128",
        "logger.progress_bar=false",
        "logger.checkpoint=false",
        "logger.log_every_frames=64",
    ]
    r = subprocess.run(
        [
            sys.executable,
            str(ROOT / "recipes" / "atari_expert.py"),
            f"out_dir={tmp_path}/e",
            "logger.eval_episodes=2",
            *common,
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert r.returncode == 0 and "evaluation: mean score" in r.stdout, r.stderr[-2000:]
    summary = json.loads((tmp_path / "e" / "summary.json").read_text())
    assert summary["evaluation"]["episodes"] == 2 and len(summary["evaluation"]["scores"]) == 2
    assert torch.load(tmp_path / "e" / "model.pt", weights_only=False)["evaluation"] == summary["evaluation"]
    r = subprocess.run(
        [
            sys.executable,
            str(ROOT / "recipes" / "atari_eval.py"),
            f"checkpoint={tmp_path}/e/model.pt",
            "episodes=1",
            "num_envs=1",
            "progress=false",
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert r.returncode == 0 and "over 1 episodes" in r.stdout, r.stderr[-2000:]
    assert json.loads((tmp_path / "e" / "eval.json").read_text())["episodes"] == 1
    r = subprocess.run(
        [
            sys.executable,
            str(ROOT / "recipes" / "atari_demos.py"),
            f"expert={tmp_path}/e/model.pt",
            f"out={tmp_path}/d",
            "num_trajectories=2",
            "num_envs=2",
            "max_steps=8",
            "progress=false",
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert r.returncode == 0 and "2 Pong trajectories" in r.stdout, r.stderr[-2000:]
    r = subprocess.run(
        [
            sys.executable,
            str(ROOT / "recipes" / "atari.py"),
            f"out_dir={tmp_path}/h",
            f"demo.path={tmp_path}/d",
            "loss.bc_start_frames=32",
            *common,
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert r.returncode == 0 and "hybrid_dual" in r.stdout, r.stderr[-2000:]


def test_shared_feature_a2c_path_equals_plain_a2c_loss():
    """Stored collection values + NextStateValueHook + the encoder's feature reuse
    give the same A2C loss and gradients as TorchRL's A2CLoss computing everything."""
    from torchrl_hybrid.trainers.hooks import NextStateValueHook
    from torchrl_hybrid.variants import VARIANTS, make_hybrid_loss

    torch.manual_seed(0)
    env = AtariEnv("Pong", 2, num_threads=1)
    actor, critic, enc, policy = make_atari_actor_critic(env.n_actions)
    batch = next(iter(Collector(env, policy, frames_per_batch=10, total_frames=10)))
    assert "state_value" in batch.keys()
    batch["next", "done"][0, 2] = True  # force an episode end inside the rollout
    batch["next", "truncated"][0, 2] = True
    fast = make_hybrid_loss(VARIANTS["a2c"], actor, critic, None, value_estimator_kwargs={"skip_existing": True})
    plain = make_hybrid_loss(VARIANTS["a2c"], actor, critic, None)
    grads = []
    for loss, b in ((fast, NextStateValueHook(critic)(batch.clone())), (plain, batch.clone().exclude("state_value"))):
        enc._cache = None
        out = loss(b)
        sum(v for k, v in out.items() if k.startswith("loss_")).backward()
        grads.append(
            (
                [out[k].detach() for k in ("loss_objective", "loss_critic", "loss_entropy")],
                enc.convs[0].weight.grad.clone(),
            )
        )
        for p in list(actor.parameters()) + list(critic.parameters()):
            p.grad = None
    for a, b in zip(grads[0][0], grads[1][0]):
        assert torch.allclose(a, b, atol=1e-5)
    assert torch.allclose(grads[0][1], grads[1][1], atol=1e-5)
    env.close()


def test_encoder_feature_reuse_is_exact():
    torch.manual_seed(0)
    enc = AtariEncoder()
    obs = torch.randint(0, 255, (4, 3, 4, 84, 84), dtype=torch.uint8)
    a = enc(obs)
    b = enc(obs.reshape(12, 4, 84, 84))  # a view of the same storage: reused
    assert b.shape == (12, 512) and torch.equal(b, a.reshape(12, 512))
    assert b.grad_fn is not None and b.data_ptr() == a.data_ptr()
    other = obs.clone()
    other[0, 0, 0, 0, 0] += 1
    assert enc(other).data_ptr() != a.data_ptr()  # another tensor: recomputed
    obs[0, 0, 0, 0, 0] += 1  # in-place change of the cached input: recomputed
    c = enc(obs)
    assert torch.allclose(c, enc._forward(obs))
    with torch.no_grad():
        assert enc(obs).grad_fn is None  # no-grad calls never get grad-mode features


def test_inverse_model_loss_is_unchanged_by_feature_reuse():
    from tensordict import TensorDict

    torch.manual_seed(0)
    actor, critic, enc, _ = make_atari_actor_critic(6)
    idm = DualInverseDynamics(enc, 6, rank=8)
    loss = DualInverseDynamicsLoss(idm, action_coeff=1.0)
    td = TensorDict(
        {
            "observation": torch.randint(0, 255, (3, 2, 4, 84, 84), dtype=torch.uint8),
            "action": torch.randint(6, (3, 2)),
            ("next", "observation"): torch.randint(0, 255, (3, 2, 4, 84, 84), dtype=torch.uint8),
        },
        [3, 2],
    )
    results = []
    for warm in (True, False):
        enc._cache = None
        if warm:
            actor.get_dist(td.select("observation"))  # populates the cache with the policy's features
        out = loss(td)
        sum(v for k, v in out.items() if k.startswith("loss_")).backward()
        results.append((out["loss_inverse"].detach(), enc.convs[0].weight.grad.clone()))
        for p in list(idm.parameters()) + list(actor.parameters()):
            p.grad = None
    assert torch.allclose(results[0][0], results[1][0], atol=1e-6)
    assert torch.allclose(results[0][1], results[1][1], atol=1e-5)


def _count_rows(enc):
    rows = []
    enc.convs.register_forward_hook(lambda m, inp, out: rows.append(inp[0].shape[0]))
    return rows


def test_next_observation_features_are_reused_exactly():
    torch.manual_seed(0)
    enc = AtariEncoder()
    rows = _count_rows(enc)
    obs = torch.randint(0, 255, (3, 5, 4, 84, 84), dtype=torch.uint8)
    nxt = torch.randint(0, 255, (3, 5, 4, 84, 84), dtype=torch.uint8)
    nxt[:, :-1] = obs[:, 1:]  # a rollout: the next observation is the next step's observation ...
    nxt[1, 2] = torch.randint(0, 255, (4, 84, 84), dtype=torch.uint8)  # ... except where an episode ended
    f_obs = enc(obs)
    f_next = enc(nxt)
    assert rows == [15, 4]  # the CNN ran on 3 last steps + 1 episode end only
    assert f_next.shape == (3, 5, 512) and torch.allclose(f_next, enc._forward(nxt), atol=1e-5)
    assert torch.equal(f_next[0, :-1], f_obs[0, 1:])
    with torch.no_grad():
        rows.clear()
        assert torch.equal(enc(obs), f_obs.detach()) and rows == []  # no-grad reuses grad features, detached
        assert enc(nxt).grad_fn is None and rows == [15]  # no shifting without grad (collection)


def test_inverse_model_gradients_are_unchanged_by_next_state_reuse():
    from tensordict import TensorDict

    torch.manual_seed(0)
    actor, critic, enc, _ = make_atari_actor_critic(6)
    idm = DualInverseDynamics(enc, 6, rank=8)
    loss = DualInverseDynamicsLoss(idm, action_coeff=1.0, embedding_coeff=0.1)
    obs = torch.randint(0, 255, (2, 4, 4, 84, 84), dtype=torch.uint8)
    nxt = torch.randint(0, 255, (2, 4, 4, 84, 84), dtype=torch.uint8)
    nxt[:, :-1] = obs[:, 1:]
    td = TensorDict({"observation": obs, "action": torch.randint(6, (2, 4)), ("next", "observation"): nxt}, [2, 4])
    results = []
    for reuse in (True, False):
        enc._cache, enc.reuse_features = None, reuse
        out = loss(td)
        sum(v for k, v in out.items() if k.startswith("loss_")).backward()
        results.append([out["loss_inverse"].detach()] + [p.grad.clone() for p in idm.parameters()])
        idm.zero_grad(set_to_none=True)
    for a, b in zip(*results):
        assert torch.allclose(a, b, atol=1e-5, rtol=1e-4)


def test_orthogonal_initialisation():
    actor, critic, enc, _ = make_atari_actor_critic(6)
    w = enc.convs[0].weight.reshape(32, -1)
    assert torch.allclose(w @ w.T, 2.0 * torch.eye(32), atol=1e-4)  # orthogonal rows, gain sqrt(2)
    head = actor.module[0].module[1].module
    assert head.weight.abs().max() < 0.05 and torch.equal(head.bias, torch.zeros(6))
    with pytest.raises(ValueError, match="init"):
        make_atari_actor_critic(6, init="xavier")


def test_compare_recipe_gives_in_process_runs_their_threads():
    """workers=1 trains in the recipe's own process: the recipe sets its torch threads to the
    runs' (two such sweeps side by side with base.threads=1 once ran at torch's default of 2
    threads each, 4 busy threads on 2 cores); worker processes set their own."""
    from torchrl_hybrid.experiments.atari_compare import CompareConfig

    assert CompareConfig(workers=1, base={"threads": 1}).process_threads() == 1
    assert CompareConfig(workers=1).process_threads() == 2
    assert CompareConfig(workers=2, base={"threads": 1}).process_threads() is None
    assert CompareConfig(workers=1, launcher="ray").process_threads() is None
    assert CompareConfig(workers=2).run_threads == 1 and CompareConfig(workers=1).run_threads == 2


def test_compare_runs_resumes_and_aggregates(pong_demos, tmp_path, capsys):
    from torchrl_hybrid.experiments.atari_compare import CompareConfig, run_compare

    base = {k: v for k, v in TINY.items() if k != "total_frames"}
    cfg = CompareConfig(
        games=["Pong"],
        variants=["a2c", "hybrid_dual"],
        seeds=[0],
        total_frames=256,
        out_dir=str(tmp_path),
        demos={"Pong": str(pong_demos / "demos")},
        workers=1,
        base=base,
    )
    (tmp_path / "summary.json").write_text(json.dumps({"Breakout": ["an earlier comparison's table"]}))
    with pytest.warns(UserWarning, match="'Breakout' in summary.json is not a comparison table"):
        result = run_compare(cfg)
    assert (tmp_path / "overview.png").stat().st_size > 0  # every game of the out_dir in one figure
    assert [t["variant"] for t in result["Pong"]] == ["a2c", "hybrid_dual"]
    # the out_dir's summary.json gains Pong and keeps the other game's table
    assert json.loads((tmp_path / "summary.json").read_text()) == {
        "Breakout": ["an earlier comparison's table"],
        **json.loads(json.dumps(result)),
    }
    assert result["Pong"][0]["idm_accuracy_expert"] is None and 0 <= result["Pong"][1]["idm_accuracy_expert"] <= 1
    for f in ("curves.csv", "summary.csv", "summary.md", "comparison.png"):
        assert (tmp_path / "Pong" / f).stat().st_size > 0
    md = (tmp_path / "Pong" / "summary.md").read_text()
    assert (
        "| hybrid_dual | 1 |" in md and "too few seeds (0 vs 0" in md and "along the run" in md
    )  # no episode ended in 256 frames
    rows = (tmp_path / "Pong" / "curves.csv").read_text().splitlines()
    assert (
        rows[0] == "variant,seed,frames,episodes,return_mean,idm_accuracy_expert,idm_accuracy,entropy,loss_bc,grad_norm"
    )
    assert all(r.split(",")[-1] for r in rows[1:])  # every update logs its gradient norm
    assert len(rows) == 1 + 2 * 3  # 3 logged points a run
    capsys.readouterr()
    run_compare(cfg)  # finished runs are not run again
    assert "0 run(s) to do" in capsys.readouterr().out
    # analyse_only: nothing is started (no demos needed); the unfinished run is named and left out
    only = CompareConfig(
        games=["Pong"],
        variants=["a2c", "hybrid_dual", "hybrid_dual_soft"],
        seeds=[0],
        out_dir=str(tmp_path),
        analyse_only=True,
    )
    assert [t["variant"] for t in run_compare(only)["Pong"]] == ["a2c", "hybrid_dual"]
    assert "1 run(s) not finished, left out: Pong/hybrid_dual_soft_s0" in capsys.readouterr().out
    assert not (tmp_path / "Pong" / "hybrid_dual_soft_s0").exists()
    # an analysis (or a sweep) of some arms keeps the folder's other finished runs in its tables and
    # in summary.json, its own arms first (it used to rewrite them with its own runs only)
    some = CompareConfig(games=["Pong"], variants=["hybrid_dual"], seeds=[1], out_dir=str(tmp_path), analyse_only=True)
    assert [t["variant"] for t in run_compare(some)["Pong"]] == ["hybrid_dual", "a2c"]
    assert "| a2c | 1 |" in (tmp_path / "Pong" / "summary.md").read_text()
    assert [t["variant"] for t in json.loads((tmp_path / "summary.json").read_text())["Pong"]] == ["hybrid_dual", "a2c"]
    with pytest.raises(FileNotFoundError, match="no finished run"):
        run_compare(CompareConfig(games=["Qbert"], variants=["a2c"], out_dir=str(tmp_path), analyse_only=True))
    with pytest.raises(ValueError, match=r"\+demos.Breakout=<folder>"):
        run_compare(CompareConfig(games=["Breakout"], out_dir=str(tmp_path)))
    with pytest.raises(FileNotFoundError, match="holds no dataset"):
        run_compare(CompareConfig(games=["Pong"], out_dir=str(tmp_path), demos={"Pong": str(tmp_path)}))
    with pytest.raises(ValueError, match="unknown Atari variant"):
        run_compare(CompareConfig(variants=["ppo"], out_dir=str(tmp_path)))
    with pytest.raises(ValueError, match="cannot take a variant's name"):
        run_compare(CompareConfig(variants=["a2c"], arms={"a2c": {"variant": "a2c"}}, out_dir=str(tmp_path)))
    with pytest.raises(ValueError, match=r"Pong/typo: unknown config key 'loss.bc_lables'"):
        run_compare(
            CompareConfig(
                games=["Pong"],
                variants=["typo"],
                out_dir=str(tmp_path / "t"),
                base=base,
                arms={"typo": {"variant": "a2c", "loss": {"bc_lables": "soft"}}},
            )
        )
    assert not (tmp_path / "t").exists()  # refused before any run started
    # another comparison drawn beside this one's runs, under labels, without running it again; its
    # second arm is a named variant with overrides (a robust one of recipes/config/arms/atari.yaml), run in <arm>_s<seed>
    beside = CompareConfig(
        games=["Pong"],
        variants=["a2c", "hybrid_dual_soft"],
        seeds=[0],
        total_frames=256,
        out_dir=str(tmp_path / "b"),
        demos={"Pong": str(pong_demos / "demos")},
        workers=1,
        base=base,
        baselines={"first": str(tmp_path)},
        label="again",
    )
    table = run_compare(beside)["Pong"]
    assert [t["variant"] for t in table] == [
        "a2c (again)",
        "hybrid_dual_soft (again)",
        "a2c (first)",
        "hybrid_dual (first)",
    ]
    assert table[2]["seeds"] == 1 and table[2]["frames_per_s"] == result["Pong"][0]["frames_per_s"]
    run_cfg = json.loads((tmp_path / "b" / "Pong" / "hybrid_dual_soft_s0" / "config.json").read_text())
    assert run_cfg["variant"] == "hybrid_dual" and run_cfg["loss"]["bc_labels"] == "soft"
    assert json.loads((tmp_path / "b" / "Pong" / "a2c_s0" / "config.json").read_text())["loss"]["bc_labels"] == "argmax"


def test_sweep_progress_counts_logged_frames(tmp_path):
    from torchrl_hybrid.experiments.atari_compare import SweepProgress

    logging, done, new = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for d in (logging, done):
        d.mkdir()
    (logging / "metrics.csv").write_text("frames,return_mean\n1000,1.0\n2500,2.0\n")
    (done / "metrics.csv").write_text("frames,return_mean\n5000,3.0\n")
    (done / "summary.json").write_text("{}")
    progress = SweepProgress([logging, done, new], frames_per_run=5000, disable=True)
    assert progress.bar.total == 15000 and progress.bar.n == 7500  # a resumed run's frames count from the start
    with open(logging / "metrics.csv", "a") as f:
        f.write("4000,2.5\n41")  # a row being written is not read
    assert progress.refresh() == 9000
    new.mkdir()
    (new / "metrics.csv").write_text("frames,return_mean\n" + "".join(f"{i * 8},0.0\n" for i in range(1, 600)))
    assert progress.refresh() == 9000 + 4792  # a file longer than the tail that is read


def test_comparison_states_faster_or_slower_than_a2c_only_with_3_seeds_each(tmp_path):
    from torchrl_hybrid.experiments.atari_compare import _summary_markdown, _versus_reference

    def row(variant, auc, acc=None):
        return {
            "variant": variant,
            "seeds": len(auc),
            "final_per_seed": auc,
            "final_mean": float(sum(auc) / len(auc)),
            "final_ci95": None,
            "auc_per_seed": auc,
            "auc_mean": float(sum(auc) / len(auc)),
            "auc_ci95": None,
            "idm_accuracy_expert": acc,
        }

    table = [
        row("a2c", [10.0, 11.0, 12.0]),
        row("fast", [20.0, 21.0, 22.0], 0.7),
        row("same", [9.0, 11.5, 12.5], 0.5),
        row("slow", [1.0, 2.0, 3.0]),
        row("two", [30.0, 31.0]),
        row("stalled", [30.0, 31.0, float("nan")]),
    ]
    _versus_reference(table)
    by = {t["variant"]: t for t in table}
    assert by["a2c"]["verdict_vs_a2c"] == "" and by["a2c"]["auc_minus_a2c"] is None
    assert by["fast"]["verdict_vs_a2c"] == "faster" and by["fast"]["auc_minus_a2c"] == 10.0
    lo, hi = by["fast"]["auc_minus_a2c_ci95"]
    assert 0 < lo < 10 < hi
    assert by["fast"]["auc_vs_a2c_p"] == pytest.approx(0.1)  # the smallest p of 3 seeds against 3
    assert by["slow"]["verdict_vs_a2c"] == "slower"
    assert by["same"]["verdict_vs_a2c"] == "not distinguishable" and by["same"]["auc_vs_a2c_p"] > 0.5
    # 2 seeds, or a seed without a score (no episode ended), give no verdict
    assert by["two"]["verdict_vs_a2c"].startswith("too few seeds (2 vs 3")
    assert by["stalled"]["verdict_vs_a2c"].startswith("too few seeds (2 vs 3")
    md = _summary_markdown("Breakout", table, 200_000).splitlines()
    assert md[0] == "### Breakout" and "last 200k game frames" in md[2]
    assert md[7].startswith("| fast | 3 | 20.00, 21.00, 22.00 | 21.00 |") and md[7].endswith("p = 0.10 | faster |")
    assert "| 70.0% |" in md[7] and "| 30.00, 31.00, – |" in md[11]
    md = _summary_markdown(
        "Breakout",
        table[:2],
        200_000,
        {"a2c": ([1_000_000, 2_000_000], [1.5, 3.0]), "fast": ([1_000_000, 2_000_000], [2.0, float("nan")])},
    )
    assert md.splitlines()[-4:] == [
        "| variant | 1M | 2M |",
        "|---|---|---|",
        "| a2c | 1.50 | 3.00 |",
        "| fast | 2.00 | – |",
    ]
    # no a2c in the comparison: no verdicts at all
    table = [row("fast", [20.0, 21.0, 22.0])]
    _versus_reference(table)
    assert table[0]["verdict_vs_a2c"] == "" and "| – | – |" in _summary_markdown("Pong", table, 100_000)
    # a comparison drawn beside a baseline folder's a2c (label): that a2c is the reference
    table = [
        row("hybrid_dual (soft)", [1.0, 2.0, 3.0]),
        row("a2c (paper settings)", [10.0, 11.0, 12.0]),
        row("hybrid_dual (paper settings)", [20.0, 21.0, 22.0]),
    ]
    _versus_reference(table)
    assert [t["verdict_vs_a2c"] for t in table] == ["slower", "", "faster"]


def test_each_named_arm_states_the_one_option_it_adds_to_its_base():
    from torchrl_hybrid.experiments.arms import named_arms
    from torchrl_hybrid.experiments.atari_compare import CompareConfig, option_text

    ROBUST_ARMS = named_arms("atari")

    cfg = CompareConfig(variants=list(ROBUST_ARMS), analyse_only=True).validate()
    bases = cfg.bases()
    assert set(bases) == set(ROBUST_ARMS)  # every robust arm is measured against the arm without its option
    assert bases["hybrid_dual_gate"] == ("hybrid_dual_soft", "loss.bc_confidence=0.6")
    assert bases["hybrid_dual_floor"] == ("hybrid_dual", "loss.bc_entropy_floor=1.0")
    assert bases["hybrid_dual_ready_anneal"] == ("hybrid_dual_ready", "loss.bc_anneal_frames=2000000")
    assert bases["hybrid_dual_soft_anneal_own"] == ("hybrid_dual_soft_anneal", "idm_encoder=own, optim.clip=per_group")
    # base is the analysis' word, not a training setting: the run's overrides do not hold it
    assert "base" not in cfg.arm("hybrid_dual_gate")[1]
    assert (
        option_text(("bc_dual", {"loss": {"bc_coeff": 2.0}}), ("hybrid_dual", {"loss": {"bc_labels": "soft"}}))
        == "variant=bc_dual, loss.bc_coeff=2.0, loss.bc_labels=default"
    )
    # an arm of one's own may name a base; a base that is no variant or arm is refused by name
    mine = CompareConfig(
        variants=["half"],
        analyse_only=True,
        arms={
            "half": {
                "variant": "hybrid_dual",
                "base": "hybrid_dual_soft",
                "loss": {"bc_labels": "soft", "bc_coeff": 0.5},
            }
        },
    ).validate()
    assert mine.bases()["half"] == ("hybrid_dual_soft", "loss.bc_coeff=0.5") and mine.arm("half")[1] == {
        "loss": {"bc_labels": "soft", "bc_coeff": 0.5}
    }
    for base in ("hybrid_dual_sofft", "half"):
        with pytest.raises(ValueError, match=rf"arms.half.base='{base}': name the variant or arm"):
            CompareConfig(
                variants=["half"], analyse_only=True, arms={"half": {"variant": "hybrid_dual", "base": base}}
            ).validate()


def test_option_effects_compare_each_arm_with_its_base_only_with_3_seeds_each():
    from torchrl_hybrid.experiments.atari_compare import _summary_markdown, _versus_reference, option_effects

    def row(variant, auc):
        return {
            "variant": variant,
            "seeds": len(auc),
            "final_per_seed": auc,
            "final_mean": float(sum(auc) / len(auc)),
            "final_ci95": None,
            "auc_per_seed": auc,
            "auc_mean": float(sum(auc) / len(auc)),
            "auc_ci95": None,
            "idm_accuracy_expert": None,
        }

    bases = {
        "soft": ("paper", "loss.bc_labels=soft"),
        "gate": ("soft", "loss.bc_confidence=0.6"),
        "floor": ("paper", "loss.bc_entropy_floor=1.0"),
        "anneal": ("soft", "loss.bc_anneal_frames=2"),
        "ready": ("paper", "loss.bc_ready_accuracy=0.4"),
        "own": ("anneal", "idm_encoder=own"),
    }
    table = [
        row("a2c", [10.0, 11.0, 12.0]),
        row("paper", [1.0, 2.0, 3.0]),
        row("soft", [5.0, 6.0, 7.0]),
        row("gate", [5.5, 6.2, 6.9]),
        row("floor", [0.0, 0.5, 1.0]),
        row("anneal", [8.0, 9.0]),
        row("ready", [1.0, 2.0, float("nan")]),
        row("soft (strong demos)", [1.0, 1.5, 2.0]),
        row("paper (strong demos)", [3.0, 3.5, 4.0]),
    ]
    _versus_reference(table)
    option_effects(table, bases)
    by = {t["variant"]: t for t in table}
    assert by["a2c"]["option"] == by["paper"]["option"] == "" and by["a2c"]["auc_minus_base"] is None
    assert by["soft"]["option_effect"] == "raises the AUC" and by["soft"]["auc_minus_base"] == 4.0
    assert by["soft"]["option_base"] == "paper" and by["soft"]["auc_vs_base_p"] == pytest.approx(0.1)
    assert by["gate"]["option_effect"] == "no measurable effect" and by["gate"]["auc_vs_base_p"] > 0.5
    assert by["floor"]["option_effect"] == "lowers the AUC" and by["floor"]["auc_minus_base"] == -1.5
    assert by["anneal"]["option_effect"].startswith("too few seeds (2 vs 3")
    assert by["ready"]["option_effect"].startswith("too few seeds (2 vs 3")  # a seed without a score
    # a labelled arm is compared with its base of the same label, not with the unlabelled one
    strong = by["soft (strong demos)"]
    assert strong["option_base"] == "paper (strong demos)" and strong["option_effect"] == "lowers the AUC"
    assert strong["auc_minus_base"] == -2.0 and strong["verdict_vs_a2c"] == "slower"
    # an arm whose base has no finished run says so
    table = [row("own", [1.0, 2.0, 3.0])]
    option_effects(table, bases)
    assert table[0]["option_effect"] == "no finished anneal run here to compare with"
    md = _summary_markdown("Breakout", [*[by[v] for v in ("a2c", "paper", "soft", "gate")]], 200_000)
    lines = md.splitlines()
    assert "| arm | option | without it (base) | AUC − base | effect |" in lines
    assert "| soft | `loss.bc_labels=soft` | paper | +4.00 [+2.67, +5.33], p = 0.10 | raises the AUC |" in lines
    assert not any(line.startswith("| a2c | `") for line in lines)  # rows without a base are not in it


def test_effects_figure_draws_the_options_with_an_interval(tmp_path):
    from torchrl_hybrid.experiments.atari_compare import effects_figure, option_effects

    def row(variant, auc):
        return {"variant": variant, "seeds": len(auc), "auc_per_seed": auc, "final_per_seed": auc}

    bases = {"soft": ("paper", "loss.bc_labels=soft"), "gate": ("soft", "loss.bc_confidence=0.6")}
    breakout = [row("paper", [1.0, 2.0, 3.0]), row("soft", [5.0, 6.0, 7.0]), row("gate", [5.0, 6.0])]
    pong = [row("paper", [1.0, 2.0, 3.0])]
    for t in (breakout, pong):
        option_effects(t, bases)
    assert effects_figure({"Breakout": breakout, "Pong": pong, "Qbert": ["old"]}, tmp_path / "e.png") == {
        "Breakout": ["soft"]
    }  # the gate has 2 seeds: no interval, not drawn; Pong has no effect to draw
    assert (tmp_path / "e.png").stat().st_size > 0
    with pytest.raises(ValueError, match="no arm in summary has a measured option effect"):
        effects_figure({"Pong": pong}, tmp_path / "none.png")
    assert not (tmp_path / "none.png").exists()


def test_overview_figure_draws_every_game_against_a2c(tmp_path):
    import numpy as np

    from torchrl_hybrid.experiments.atari_compare import _versus_reference, overview_figure

    def row(variant, auc, final):
        mean = lambda xs: float(np.nanmean(np.array(xs, float)))  # noqa: E731
        return {
            "variant": variant,
            "seeds": len(auc),
            "auc_per_seed": auc,
            "auc_mean": mean(auc),
            "auc_ci95": None,
            "final_per_seed": final,
            "final_mean": mean(final),
            "final_ci95": None,
        }

    # a2c listed last is drawn on top; a seed without a final score (None in summary.json) is no dot
    breakout = [
        row("hybrid_dual", [8.0, 11.0, 2.0], [18.0, None, 19.0]),
        row("a2c", [20.0, 21.0, 17.0], [48.0, 45.0, 51.0]),
    ]
    for t in breakout:
        t["auc_ci95"] = [min(t["auc_per_seed"]), max(t["auc_per_seed"])]
    _versus_reference(breakout)
    summary = {
        "Breakout": breakout,
        "Pong": [row("hybrid_dual", [-20.0], [-19.0])],  # no a2c: drawn, no band
        "Qbert": ["an older entry"],
    }
    with pytest.warns(UserWarning, match="'Qbert' in summary.json is not a comparison table"):
        drawn = overview_figure(summary, tmp_path / "o.png")
    assert drawn == {"Breakout": ["a2c", "hybrid_dual"], "Pong": ["hybrid_dual"]}
    assert (tmp_path / "o.png").stat().st_size > 0
    with pytest.raises(ValueError, match="no comparison table"):
        overview_figure({"Qbert": []}, tmp_path / "none.png")
    assert not (tmp_path / "none.png").exists()


def test_fused_collection_policy_equals_actor_and_critic():
    from tensordict import TensorDict
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    torch.manual_seed(0)
    actor, critic, enc, policy = make_atari_actor_critic(6)
    obs = torch.randint(0, 255, (2, 3, 4, 84, 84), dtype=torch.uint8)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = policy(TensorDict({"observation": obs}, [2, 3]))
        ref = actor(TensorDict({"observation": obs}, [2, 3]))
        value = critic(TensorDict({"observation": obs}, [2, 3]))["state_value"]
    assert torch.equal(td["action"], ref["action"])
    assert torch.allclose(td["action_log_prob"], ref["action_log_prob"], atol=1e-6)
    assert torch.allclose(td["state_value"], value, atol=1e-6) and td["state_value"].shape == (2, 3, 1)
    # sampling: frequencies follow the actor's distribution
    head = policy.module.policy_head
    with torch.no_grad():
        head.bias.copy_(torch.tensor([0.0, 1.0, 2.0, -1.0, 0.5, 0.0]))
        head.weight.zero_()
        one = obs[:1, :1].expand(1, 4000, 4, 84, 84).contiguous()
        with set_exploration_type(ExplorationType.RANDOM):
            td = policy(TensorDict({"observation": one}, [1, 4000]))
    freq = torch.bincount(td["action"].flatten(), minlength=6).float() / 4000
    assert torch.allclose(freq, head.bias.softmax(-1), atol=0.035)  # 4.5 binomial std
    assert torch.allclose(td["action_log_prob"], head.bias.log_softmax(-1)[td["action"]], atol=1e-5)


def test_a_run_resumes_from_its_checkpoint(tmp_path):
    cfg = tiny(tmp_path, variant="a2c", logger={"checkpoint": True})
    first = train_atari(cfg)
    assert first["frames"] == 256 and (tmp_path / "checkpoint").exists()
    longer = tiny(tmp_path, variant="a2c", total_frames=512, resume=True, logger={"checkpoint": True})
    s = train_atari(longer)
    assert s["frames"] == 512 and s["resumed_from_frames"] == 256
    frames = [int(line.split(",")[0]) for line in (tmp_path / "metrics.csv").read_text().splitlines()[1:]]
    assert frames == sorted(set(frames)) and frames[-1] == 512 and 256 in frames
    with pytest.raises(ValueError, match=r"other settings for \['seed'\]"):
        train_atari(tiny(tmp_path, variant="a2c", seed=3, total_frames=768, resume=True, logger={"checkpoint": True}))


def test_atari_recipes_name_missing_arguments():
    for recipe, args, key in (("atari_eval.py", [], "checkpoint"), ("atari_demos.py", ["expert=x.pt"], "out")):
        r = subprocess.run(
            [sys.executable, str(ROOT / "recipes" / recipe), *args], capture_output=True, text=True, timeout=120
        )
        assert r.returncode == 2 and f"error: {key}=... is required" in r.stderr, r.stderr[-1000:]


def test_demo_recording_is_seeded(pong_demos, tmp_path):
    expert = pong_demos / "expert" / "model.pt"
    runs = [
        record_demos(
            expert,
            tmp_path / f"d{i}",
            num_trajectories=2,
            num_envs=2,
            max_steps=30,
            seed=5,
            progress=False,
            device="cpu",
        )
        for i in range(2)
    ]
    assert runs[0]["lengths"] == runs[1]["lengths"]
    a, _ = load_demos(tmp_path / "d0")
    b, _ = load_demos(tmp_path / "d1")
    assert torch.equal(a["expert_action"], b["expert_action"])


def test_demos_of_random_frames_are_refused(pong_demos, tmp_path):
    demos, meta = load_demos(pong_demos / "demos")
    fake = demos.clone()
    fake["observation"] = torch.randint(0, 256, fake["observation"].shape, dtype=torch.uint8)
    fake["next", "observation"] = torch.randint(0, 256, fake["observation"].shape, dtype=torch.uint8)
    from torchrl_hybrid.data import save_demos

    save_demos(fake, tmp_path / "fake", meta)
    with pytest.raises(ValueError, match="do not share their stacked frames"):
        train_atari(tiny(tmp_path / "run", variant="hybrid_dual", demo={"path": str(tmp_path / "fake")}))


@pytest.mark.parametrize("kind", ["multi_sync", "ray"])
def test_hybrid_runs_with_its_games_in_worker_processes(pong_demos, tmp_path, kind):
    """collector.backend=multi_sync|ray: the games step in 2 workers (one env each), the
    learner's weights reach them after every batch; the hybrid trains as with one process."""
    if kind == "ray":
        ray = pytest.importorskip("ray")
    try:
        s = train_atari(
            tiny(
                tmp_path,
                variant="hybrid_dual",
                collector={"backend": kind, "workers": 2},
                demo={"path": str(pong_demos / "demos")},
            )
        )
    finally:
        if kind == "ray":
            ray.shutdown()
    assert s["frames"] == 256 and s["config"]["collector"]["backend"] == kind
    rows = list(csv.DictReader((tmp_path / "metrics.csv").open()))
    assert int(rows[-1]["frames"]) == 256 and "loss_bc" in rows[-1] and "loss_objective" in rows[-1]
    with pytest.raises(ValueError, match="must divide env.num_envs"):
        tiny(tmp_path / "bad", variant="a2c", collector={"backend": kind, "workers": 3}).validate()


def test_compile_setting_compiles_the_shared_cnn(tmp_path):
    from torchrl_hybrid.families.atari import build_atari

    run = build_atari(tiny(tmp_path / "c", variant="a2c", compile="default"))
    assert run.encoder._compiled is not None  # collection and learner share the compiled CNN
    run.collector.shutdown()
    run.lock.close()
    with pytest.raises(ValueError, match=r"compile='fast': choose one of \('off', 'default'"):
        tiny(tmp_path / "d", compile="fast").validate()


def test_action_effect_diagnostic_counts_the_actions_s_and_next_s_tell_apart(tmp_path):
    """benchmarks/atari_action_effect.py, the mechanism behind the Atari results: on Qbert
    almost no action changes the next screen (the joystick is read only when Qbert lands),
    on Pong the paddle's three moves are told apart and the FIRE variants are not."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("action_effect", ROOT / "benchmarks" / "atari_action_effect.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    qbert, pong = mod.action_classes("Qbert", 50), mod.action_classes("Pong", 50)
    for r in (qbert, pong):
        assert r["actions"] == 6 and sum(r["classes_histogram"].values()) == 50
    assert qbert["no_action_visible"] > 0.8 and qbert["mean_classes"] < 1.5
    assert (
        pong["no_action_visible"] < 0.2 and 2.0 < pong["mean_classes"] <= 3.0
    )  # NOOP/FIRE, the two ups, the two downs
    saved = tmp_path / "effect.json"
    saved.write_text(json.dumps([qbert, pong]))  # as --out writes it (JSON turns the histogram's keys to strings)
    mod.plot(json.loads(saved.read_text()), tmp_path / "effect.png")
    assert (tmp_path / "effect.png").stat().st_size > 10_000
    with pytest.raises(ValueError, match="no ROM"):
        mod.action_classes("NotAGame", 1)


@pytest.mark.parametrize("idm_encoder", ["shared", "own"])
def test_inverse_label_diagnostic_reads_back_the_trained_models(pong_demos, tmp_path, idm_encoder):
    """benchmarks/atari_inverse_labels.py rebuilds the actor and the inverse model (one shared
    CNN, or one each) from model.pt and gives the labels the trained run's own modules give."""
    import importlib.util

    from torchrl_hybrid.families.atari import build_atari
    from torchrl_hybrid.trainers.run import finish_run

    spec = importlib.util.spec_from_file_location("inverse_labels", ROOT / "benchmarks" / "atari_inverse_labels.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    run = build_atari(
        tiny(
            tmp_path / "hybrid",
            variant="hybrid_dual",
            demo={"path": str(pong_demos / "demos")},
            idm_encoder=idm_encoder,
        )
    )
    run.trainer.train()
    demos, _ = load_demos(pong_demos / "demos")
    run.encoder.reuse_features = run.inverse_model.encoder.reuse_features = False
    with torch.no_grad():
        want = run.inverse_model.infer(demos["observation"], demos["next", "observation"])
        greedy = run.actor(demos.select("observation").clone())["logits"].argmax(-1)
    finish_run(run)
    r = mod.inverse_labels(tmp_path / "hybrid" / "model.pt", pong_demos / "demos", batch=7)
    n = len(demos)
    assert r["pairs"] == n and r["actions"] == 6
    assert r["share_labels"] == pytest.approx((torch.bincount(want, minlength=6).float() / n).tolist())
    assert r["accuracy"] == pytest.approx(float((want == demos["expert_action"]).float().mean()))
    assert r["labels_equal_agent_greedy"] == pytest.approx(float((want == greedy).float().mean()))
    assert sum(r["share_true"]) == pytest.approx(1.0) and 1 / 6 <= r["mean_confidence"] <= 1
    assert r["action_names"] == ["NOOP", "FIRE", "RIGHT", "LEFT", "RIGHTFIRE", "LEFTFIRE"]
    conf = torch.tensor(r["confusion"])  # [true, label]: its margins are the two shares, its trace the accuracy
    assert conf.sum(1).tolist() == pytest.approx(r["share_true"], abs=1e-6)
    assert conf.sum(0).tolist() == pytest.approx(r["share_labels"], abs=1e-6)
    assert float(conf.trace()) == pytest.approx(r["accuracy"], abs=1e-6)
    kept = [g["kept"] for g in r["confidence_gate"].values()]
    assert kept == sorted(kept, reverse=True) and all(0 <= k <= 1 for k in kept)
    mod.plot(r, tmp_path / "labels.png")
    assert (tmp_path / "labels.png").stat().st_size > 10_000
    with pytest.raises(ValueError, match="a2c has none"):
        mod.load_hybrid(pong_demos / "expert" / "model.pt")


def test_grad_norm_diagnostic_averages_the_logged_norms_per_window(tmp_path):
    """benchmarks/atari_grad_norms.py: the mean logged grad_norm of each (lo, hi] frame window
    and the run's clip; a window with no row is NaN, a log without grad_norm is refused."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("grad_norms", ROOT / "benchmarks" / "atari_grad_norms.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    d = tmp_path / "hybrid_dual_s0"
    d.mkdir()
    rows = [(40_000, 1.0), (80_000, 3.0), (120_000, 100.0), (240_000, 0.5), (1_000_000, 1.5)]
    (d / "metrics.csv").write_text("frames,return_mean,grad_norm\n" + "".join(f"{f},0.0,{g}\n" for f, g in rows))
    (d / "config.json").write_text(json.dumps({"optim": {"max_grad_norm": 0.5}}))
    r = mod.grad_norms(d, windows=((0, 100_000), (200_000, 2_000_000), (2_500_000, 5_000_000)))
    assert r["mean_grad_norm"][:2] == [2.0, 1.0] and math.isnan(r["mean_grad_norm"][2]) and r["clip"] == 0.5
    # optim.clip=per_group logs each group's norm: the policy's is read
    (d / "metrics.csv").write_text("frames,grad_norm_policy,grad_norm_inverse_model\n40000,0.25,9.0\n")
    assert mod.grad_norms(d)["mean_grad_norm"][0] == 0.25 and mod.grad_norms(d)["key"] == "grad_norm_policy"
    (d / "metrics.csv").write_text("frames,return_mean\n40000,0.0\n")
    with pytest.raises(ValueError, match="logs no grad_norm"):
        mod.grad_norms(d)


def test_inverse_model_with_its_own_cnn_leaves_the_policy_cnn_to_a2c(pong_demos, tmp_path):
    """idm_encoder=own: the inverse model gets a CNN of its own (same architecture, separate
    weights, in the optimiser once), its loss sends no gradient into the actor's CNN, and a run
    trains and resumes with it; a checkpoint of the other kind is not resumed."""
    from torchrl_hybrid.families.atari import build_atari
    from torchrl_hybrid.trainers.run import finish_run

    demo = {"path": str(pong_demos / "demos")}
    run = build_atari(
        tiny(tmp_path / "own", variant="hybrid_dual", demo=demo, idm_encoder="own", logger={"checkpoint": True})
    )
    shared = build_atari(tiny(tmp_path / "shared", variant="hybrid_dual", demo=demo))
    assert shared.inverse_model.encoder is shared.encoder and run.inverse_model.encoder is not run.encoder
    own_ids = {id(p) for p in run.inverse_model.encoder.parameters()}
    assert own_ids.isdisjoint(id(p) for p in run.encoder.parameters())
    ids = [id(p) for g in run.trainer.optimizer.param_groups for p in g["params"]]
    assert len(ids) == len(set(ids)) and own_ids <= set(ids) and {id(p) for p in run.encoder.parameters()} <= set(ids)
    finish_run(shared)
    batch = next(iter(run.collector))
    run.encoder.reuse_features = run.inverse_model.encoder.reuse_features = False
    run.loss.inverse_dynamics_loss(batch)["loss_inverse"].backward()
    assert all(p.grad is None or not p.grad.any() for p in run.encoder.parameters())
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in run.inverse_model.encoder.parameters())
    run.trainer.optimizer.zero_grad()
    run.encoder.reuse_features = run.inverse_model.encoder.reuse_features = True
    run.trainer.train()
    s = finish_run(run)
    assert s["frames"] == 256 - 4 * batch.numel() and 0 <= s["idm_accuracy_expert"] <= 1  # less the batch taken above
    assert json.loads((tmp_path / "own" / "config.json").read_text())["idm_encoder"] == "own"
    with pytest.raises(ValueError, match="idm_encoder"):
        build_atari(
            tiny(
                tmp_path / "own",
                variant="hybrid_dual",
                demo=demo,
                idm_encoder="shared",
                resume=True,
                total_frames=512,
                logger={"checkpoint": True},
            )
        )
    with pytest.raises(ValueError, match=r"idm_encoder='mine': choose one of \('shared', 'own'\)"):
        tiny(tmp_path / "bad", idm_encoder="mine").validate()


def test_every_named_arm_is_a_valid_atari_config():
    from torchrl_hybrid.experiments.arms import named_arms
    from torchrl_hybrid.experiments.atari_compare import CompareConfig

    ROBUST_ARMS = named_arms("atari")

    cfg = CompareConfig(variants=list(ROBUST_ARMS), analyse_only=True)
    paper = atari_config({"variant": "hybrid_dual", "demo": {"path": "demos"}})
    for name in ROBUST_ARMS:  # each a hybrid that differs from the paper's agent, with settings that validate
        variant, overrides = cfg.arm(name)
        built = atari_config({**overrides, "variant": variant, "demo": {"path": "demos"}}).validate()
        assert variant in ("hybrid_dual", "hybrid_true") and built != paper, name
    ready = atari_config({**cfg.arm("hybrid_dual_ready_anneal")[1], "demo": {"path": "demos"}})
    assert (ready.loss.bc_ready_accuracy, ready.loss.bc_anneal_frames) == (0.4, 2_000_000)


def test_init_from_warm_starts_the_networks_and_counts_their_frames(tmp_path):
    """init_from (train an expert longer): the actor and critic start from a finished run's
    model.pt, in the modules the loss and optimiser train, and the frames add up."""
    first = train_atari(tiny(tmp_path / "first", variant="a2c"))
    saved = torch.load(tmp_path / "first" / "model.pt", weights_only=False)
    assert saved["total_frames_seen"] == first["frames"] == 256
    from torchrl_hybrid.families.atari import build_atari

    run = build_atari(tiny(tmp_path / "warm", variant="a2c", seed=7, init_from=str(tmp_path / "first" / "model.pt")))
    try:
        for k, v in saved["actor"].items():
            assert torch.equal(run.actor.state_dict()[k].cpu(), v), k
        trained = [p for g in run.trainer.optimizer.param_groups for p in g["params"]]
        for v in saved["critic"].values():  # the tensors the optimiser steps hold the saved values
            assert any(p.shape == v.shape and torch.equal(p.detach().cpu(), v) for p in trained)
        assert run.init_frames == 256
        run.trainer.train()  # auto warm-up (optim.warmup_frames=None): lr rises over 100 updates of 32 frames
        assert run.trainer.collected_frames == 256
        assert [g["lr"] for g in run.trainer.optimizer.param_groups] == pytest.approx(
            [7e-4 * 256 / 3200]
        )  # a2c: one group
    finally:
        run.lock.close()
        run.collector.shutdown()
    s = train_atari(tiny(tmp_path / "warm2", variant="a2c", seed=7, init_from=str(tmp_path / "first" / "model.pt")))
    assert s["frames"] == 256 and s["total_frames_seen"] == 512 and s["init_from"].endswith("model.pt")
    again = torch.load(tmp_path / "warm2" / "model.pt", weights_only=False)["total_frames_seen"]
    assert again == 512
    meta = record_demos(
        tmp_path / "warm2" / "model.pt", tmp_path / "demos", num_trajectories=1, num_envs=1, max_steps=4, progress=False
    )
    assert meta["expert_frames"] == 512  # the weights' whole history, not this piece's 256


def test_init_from_refuses_another_game_or_a_missing_file(tmp_path):
    train_atari(tiny(tmp_path / "pong", variant="a2c"))
    with pytest.raises(ValueError, match=r"other settings for \['env.game'\].*'Pong' \(saved\) vs 'Breakout'"):
        train_atari(
            tiny(tmp_path / "b", variant="a2c", env={"game": "Breakout"}, init_from=str(tmp_path / "pong" / "model.pt"))
        )
    with pytest.raises(FileNotFoundError, match="init_from='nope.pt': no such file"):
        train_atari(tiny(tmp_path / "c", variant="a2c", init_from="nope.pt"))
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="is not a model.pt written by this pipeline"):
        train_atari(tiny(tmp_path / "d", variant="a2c", init_from=str(tmp_path / "junk.pt")))
    assert not (tmp_path / "b" / "summary.json").exists()  # a refused run writes no results


def test_oracle_arm_and_the_balance_and_label_options_run_on_atari(pong_demos, tmp_path):
    """hybrid_true (BC on the demos' true actions: a diagnostic), the BC gradient clipped apart,
    prior-corrected labels and extra BC / inverse-model updates, in the Atari pipeline."""
    demo = {"path": str(pong_demos / "demos")}
    s = train_atari(
        tiny(
            tmp_path / "a",
            variant="hybrid_dual",
            demo=demo,
            optim={"clip": "per_term"},
            loss={"bc_prior_floor": 0.05, "bc_updates": 1, "idm_updates": 1},
        )
    )
    rows = list(csv.DictReader((tmp_path / "a" / "metrics.csv").open()))
    assert s["frames"] == 256 and {"grad_norm_rl", "grad_norm_inverse_model", "grad_norm_bc"} <= set(rows[-1])
    s = train_atari(tiny(tmp_path / "b", variant="hybrid_true", demo=demo))
    rows = list(csv.DictReader((tmp_path / "b" / "metrics.csv").open()))
    assert s["frames"] == 256 and "loss_bc" in rows[-1] and "loss_inverse" not in rows[-1]
    with pytest.raises(ValueError, match="clones the expert's true actions"):
        train_atari(tiny(tmp_path / "c", variant="hybrid_true", demo=demo, loss={"bc_labels": "soft"}))
    with pytest.raises(ValueError, match="built for the gymnasium family"):
        tiny(tmp_path / "d", variant="hybrid_dual", demo=demo, loss={"explore_envs": 1}).validate()
