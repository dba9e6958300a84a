"""The batched fast path computes the same algorithm as the TorchRL pipeline."""

import pytest
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector

from torchrl_hybrid.envs import make_gym_env
from torchrl_hybrid.families.gym import GymConfig, config_from_dict
from torchrl_hybrid.families.gym_batched import (
    BatchedTabularAgents,
    LazyRMSprop,
    _Demos,
    a2c_terms,
    bc_loss_terms,
    idm_loss_terms,
    train_taxi_batched,
)
from torchrl_hybrid.modules import DualInverseDynamics, MLPInverseDynamics, OneHotEncoder, make_tabular_actor_critic
from torchrl_hybrid.variants import VARIANTS, make_hybrid_loss


def copy_into(agents, actor, critic, idm):
    """Loads TorchRL modules' weights into a 1-agent batch."""
    with torch.no_grad():
        for head, net in (("a", actor.module[0].module), ("c", critic.module)):
            agents.t[f"E_{head}"].copy_(net[1].weight.T)
            agents.p[f"W_{head}"][0].copy_(net[2].weight.T)
            agents.p[f"b_{head}"][0].copy_(net[2].bias)
        agents.t["W_s"].copy_(idm.W_s.weight.T)
        if isinstance(idm, DualInverseDynamics):
            agents.p["W_ds"][0].copy_(idm.W_ds.weight.T)
            agents.p["act_emb"][0].copy_(idm.action_embedding.weight)
            agents.p["M"][0].copy_(idm.M.permute(1, 0, 2).reshape(idm.d_state, -1))
            agents.p["N"][0].copy_(idm.N.permute(1, 0, 2).reshape(idm.d, -1))
        else:
            for i in range(2):
                agents.p[f"L{i}"][0].copy_(idm.mlp[2 * i].weight.T)
                agents.p[f"c{i}"][0].copy_(idm.mlp[2 * i].bias)
        agents.p["W_i"][0].copy_(idm.action_head.weight.T)
        agents.p["b_i"][0].copy_(idm.action_head.bias)


@pytest.mark.parametrize("kind", ["dual", "mlp"])
def test_batched_losses_equal_torchrl_losses(kind):
    torch.manual_seed(0)
    cfg = GymConfig(variant=f"hybrid_{kind}")
    actor, critic = make_tabular_actor_critic(500, 6)
    idm = (
        DualInverseDynamics(OneHotEncoder(500), 6, rank=2)
        if kind == "dual"
        else MLPInverseDynamics(OneHotEncoder(500), 6)
    )
    loss = make_hybrid_loss(VARIANTS[cfg.variant], actor, critic, idm)
    # a real rollout with short episodes, so that it holds terminations and truncations
    env = make_gym_env(num_envs=16, max_episode_steps=3, seed=1)
    batches = iter(Collector(env, actor, frames_per_batch=32, total_frames=32 * 40))
    batch = next(b for b in batches if b["next", "truncated"].any() and b["next", "done"][:, 0].any())
    # BC at the visited states (the authors' rho): the expert's pair of each visited state
    from torchrl_hybrid.data import VisitedStateSampler, make_expert_buffer, tabular_state_pairs
    from torchrl_hybrid.envs import TabularModel
    from torchrl_hybrid.experts import optimal_policy

    model = TabularModel.from_gym("Taxi-v4")
    demos = tabular_state_pairs(model, optimal_policy(model)[0])
    buffer = make_expert_buffer(demos, sampler=VisitedStateSampler(500), batch_size=32)  # ignored by this sampler
    buffer.sampler.observe(batch["observation"])
    expert = buffer.sample()
    assert expert.batch_size.numel() == batch.numel()  # every state has its pair
    ref = loss(TensorDict({"agent": batch, "expert": expert}, []))

    agents = BatchedTabularAgents(cfg, [0], 500, 6)
    copy_into(agents, actor, critic, idm)
    u = lambda key: batch[key].unsqueeze(0)  # noqa: E731
    got = a2c_terms(
        agents,
        u("observation"),
        u("action"),
        u(("next", "reward")).squeeze(-1),
        u(("next", "observation")),
        u(("next", "terminated")).squeeze(-1),
        u(("next", "done")).squeeze(-1),
        0.99,
        0.2,
        0.5,
    )
    flat = lambda key: u(key).reshape(1, -1)  # noqa: E731
    got.update(idm_loss_terms(agents, flat("observation"), flat("action"), flat(("next", "observation")), cfg.loss))
    d = _Demos([demos], 500)
    s = flat("observation")
    kk = torch.zeros(1, 1, dtype=torch.long)
    got.update(bc_loss_terms(agents, d.obs[kk, d.at[kk, s]], d.next[kk, d.at[kk, s]], d.has[kk, s], 2.0))
    assert float(got["bc_batch_size"][0]) == float(ref["bc_batch_size"]) == batch.numel()
    for k in ("loss_objective", "loss_critic", "loss_entropy", "loss_inverse", "loss_bc"):
        assert torch.allclose(ref[k], got[k][0], atol=1e-5), (k, ref[k], got[k])
    if kind == "dual":
        for k in ("loss_action_embedding", "loss_state_embedding"):
            assert torch.allclose(ref[k], got[k][0], atol=1e-5), k


def test_lazy_rmsprop_equals_dense_rmsprop_with_clipping():
    torch.manual_seed(0)
    K, rows, D = 3, 5, 4
    table = torch.randn(K * rows, D)
    dense = torch.randn(K, 2)
    ref_t, ref_d = (
        [table[k * rows : (k + 1) * rows].clone().requires_grad_() for k in range(K)],
        [dense[k].clone().requires_grad_() for k in range(K)],
    )
    refs = [torch.optim.RMSprop([ref_t[k], ref_d[k]], lr=0.1, alpha=0.9, eps=1e-5) for k in range(K)]
    lt, ld = table.clone().requires_grad_(), dense.clone().requires_grad_()
    lazy = LazyRMSprop([ld], [(lt, rows)], K, lr=0.1, alpha=0.9, eps=1e-5, max_norm=0.7)
    for step in range(6):
        idx = torch.randint(rows, (K, 2))  # each agent touches two rows
        w = torch.randn(K, 2, D)
        for k in range(K):
            loss = (ref_t[k][idx[k]] * w[k]).sum() + (ref_d[k] ** 2).sum() * step
            loss.backward()
            torch.nn.utils.clip_grad_norm_([ref_t[k], ref_d[k]], 0.7)
            refs[k].step()
            refs[k].zero_grad()
        flat = (idx + torch.arange(K).unsqueeze(1) * rows).reshape(-1)
        emb = torch.nn.functional.embedding(flat, lt, sparse=True).view(K, 2, D)
        ((emb * w).sum() + (ld**2).sum() * step).backward()
        lazy.step()
    assert torch.allclose(torch.cat(ref_t).detach(), lt.detach(), atol=1e-5)
    assert torch.allclose(torch.stack(ref_d).detach(), ld.detach(), atol=1e-5)
    dense_v = torch.cat([refs[k].state[ref_t[k]]["square_avg"] for k in range(K)])
    assert torch.allclose(dense_v, lazy.dense_state_of_sparse(0), atol=1e-6)


def tiny(tmp_path, **kw):
    d = {
        "total_frames": 640,
        "out_dir": str(tmp_path),
        "logger": {"log_every_frames": 320, "eval_episodes": 8, "final_eval_episodes": 8, "progress_bar": False},
    }
    d.update(kw)
    return config_from_dict(d)


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_batched_variants_run_and_write_outputs(tmp_path, variant):
    cfgs = [
        tiny(tmp_path / str(s), variant=variant, seed=s, demo={"eta": 0.25 * s, "epsilon": 0.1 * s}) for s in range(3)
    ]
    out = train_taxi_batched(cfgs, plot=False)
    assert [o["seed"] for o in out] == [0, 1, 2] and all(o["frames"] == 640 for o in out)
    for s in range(3):
        assert (tmp_path / str(s) / "metrics.csv").exists() and (tmp_path / str(s) / "summary.json").exists()


def test_batched_refuses_mixed_or_unsupported_configs(tmp_path):
    with pytest.raises(ValueError, match="batch them separately"):
        train_taxi_batched([tiny(tmp_path, rank=1), tiny(tmp_path, rank=2)])
    with pytest.raises(ValueError, match="curriculum"):
        train_taxi_batched([tiny(tmp_path, demo={"rho": "curriculum"})])
    with pytest.raises(ValueError, match="gym"):
        train_taxi_batched([tiny(tmp_path, env={"backend": "gym"})])
    # label options beyond the paper are not silently dropped by the fast path
    with pytest.raises(ValueError, match=r"loss.bc_labels='soft', loss.bc_anneal_frames=100 need engine=torchrl"):
        train_taxi_batched([tiny(tmp_path, loss={"bc_labels": "soft", "bc_anneal_frames": 100})])
    with pytest.raises(ValueError, match=r"optim.clip='per_group' need engine=torchrl"):
        train_taxi_batched([tiny(tmp_path, optim={"clip": "per_group"})])


@pytest.mark.slow
def test_fast_path_and_torchrl_path_learn_alike():
    """Same seeds, both paths: the greedy-return curves agree statistically."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(
        "paths_agree", Path(__file__).resolve().parents[1] / "benchmarks" / "taxi_paths_agree.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    r = mod.compare("hybrid_dual", seeds=4, frames=24_000)
    t, b = r["auc"]["torchrl"][0], r["auc"]["batched"][0]
    assert r["auc"]["p_value"] > 0.01, r
    assert abs(t - b) < 15, r
    assert -60 < b < 8 and -60 < t < 8  # both learned something (random play is about -200)
