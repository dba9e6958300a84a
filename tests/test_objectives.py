import pytest
import torch
import torch.nn.functional as F
from tensordict import TensorDict

from torchrl_hybrid.modules import DualInverseDynamics, MLPInverseDynamics, OneHotEncoder, make_tabular_actor_critic
from torchrl_hybrid.objectives import DualInverseDynamicsLoss, ExpertBCLoss, InverseDynamicsLoss
from torchrl_hybrid.trainers import VARIANTS, make_hybrid_loss


def transitions(n=12, S=7, A=4):
    return TensorDict(
        {"observation": torch.randint(S, (n,)), "action": torch.randint(A, (n,)),
         ("next", "observation"): torch.randint(S, (n,))},
        [n],
    )


def test_dual_loss_matches_its_formula_and_trains_only_the_model():
    idm = DualInverseDynamics(OneHotEncoder(7), 4, d_state=5, d=6, rank=2, n_states=7)
    loss = DualInverseDynamicsLoss(idm, action_coeff=2.0, embedding_coeff=0.1, forward_coeff=0.5)
    td = transitions()
    out = loss(td)
    t = idm.terms(td["observation"], td["action"], td["next", "observation"])
    expected = {
        "loss_inverse": 2.0 * F.cross_entropy(t["action_logits"], td["action"]),
        "loss_action_embedding": 0.1 * (t["h_a"] - t["h_a_hat"]).abs().mean(),
        "loss_state_embedding": 0.1 * (t["h_ds"] - t["h_ds_hat"]).abs().mean(),
        "loss_forward": 0.5 * F.cross_entropy(t["next_state_logits"], td["next", "observation"]),
    }
    for k, v in expected.items():
        assert torch.allclose(out[k], v, atol=1e-6), k
    acc = (t["action_logits"].argmax(-1) == td["action"]).float().mean()
    assert torch.allclose(out["idm_accuracy"], acc) and not out["idm_accuracy"].requires_grad
    sum(v for k, v in out.items() if k.startswith("loss_")).backward()
    for name, p in idm.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name


def test_mask_and_key_renaming():
    idm = MLPInverseDynamics(OneHotEncoder(7), 4, d_state=5, hidden=8)
    loss = InverseDynamicsLoss(idm)
    td = transitions().rename_key_("observation", "s")
    td["use"] = torch.arange(12) < 4
    loss.set_keys(observation="s", mask="use")
    full = loss(td)["loss_inverse"]
    logits = idm.action_logits(td["s"][:4], td["next", "observation"][:4])
    assert torch.allclose(full, F.cross_entropy(logits, td["action"][:4]))


def test_loss_errors_name_the_fix():
    with pytest.raises(ValueError, match="InverseDynamicsLoss"):
        DualInverseDynamicsLoss(MLPInverseDynamics(OneHotEncoder(7), 4))
    with pytest.raises(ValueError, match="n_states"):
        DualInverseDynamicsLoss(DualInverseDynamics(OneHotEncoder(7), 4), forward_coeff=1.0)
    loss = InverseDynamicsLoss(MLPInverseDynamics(OneHotEncoder(7), 4))
    bad = transitions()
    bad["action"] = F.one_hot(bad["action"], 4)
    with pytest.raises(ValueError, match="categorical"):
        loss(bad)


def test_bc_loss_clones_inferred_actions_without_touching_the_inverse_model():
    actor, _ = make_tabular_actor_critic(7, 4)
    idm = DualInverseDynamics(OneHotEncoder(7), 4, d_state=5, d=6)
    loss = ExpertBCLoss(actor, idm, bc_coeff=2.0)
    demos = transitions().exclude("action")
    out = loss(demos)
    labels = idm.infer(demos["observation"], demos["next", "observation"])
    assert torch.equal(demos["inferred_action"], labels)
    logits = actor.module[0](demos.select("observation"))["logits"]
    assert torch.allclose(out["loss_bc"], 2.0 * F.cross_entropy(logits, labels), atol=1e-6)
    out["loss_bc"].backward()
    assert all(p.grad is None for p in idm.parameters())
    assert all(p.grad is not None for p in actor.parameters())
    assert loss(demos[:0])["loss_bc"] == 0  # an empty expert batch adds nothing


def test_state_only_learners_never_read_expert_actions():
    """Scrambling the true-action key changes nothing for hybrid/BC losses."""
    torch.manual_seed(0)
    actor, critic = make_tabular_actor_critic(7, 4)
    idm = DualInverseDynamics(OneHotEncoder(7), 4, d_state=5, d=6)
    demos = transitions().rename_key_("action", "expert_action")
    scrambled = demos.clone()
    scrambled["expert_action"] = (scrambled["expert_action"] + 1) % 4
    for name in ("hybrid_dual", "bc_dual"):
        loss = make_hybrid_loss(VARIANTS[name], actor, critic, idm).bc_loss
        assert torch.equal(loss(demos.clone())["loss_bc"], loss(scrambled.clone())["loss_bc"])
    il = make_hybrid_loss(VARIANTS["il"], actor, critic, None).bc_loss
    assert not torch.equal(il(demos.clone())["loss_bc"], il(scrambled.clone())["loss_bc"])


def test_hybrid_loss_composes_a2c_idm_and_bc():
    actor, critic = make_tabular_actor_critic(7, 4)
    idm = DualInverseDynamics(OneHotEncoder(7), 4, d_state=5, d=6)
    loss = make_hybrid_loss(VARIANTS["hybrid_dual"], actor, critic, idm)
    agent = TensorDict(
        {"observation": torch.randint(7, (3, 2)), "action": torch.randint(4, (3, 2)),
         "next": {"observation": torch.randint(7, (3, 2)), "reward": torch.randn(3, 2, 1),
                  "done": torch.zeros(3, 2, 1, dtype=torch.bool), "terminated": torch.zeros(3, 2, 1, dtype=torch.bool)}},
        [3, 2],
    )
    expert = transitions(5).exclude("action")
    out = loss(TensorDict({"agent": agent, "expert": expert}, []))
    assert {"loss_objective", "loss_critic", "loss_entropy", "loss_inverse", "loss_action_embedding",
            "loss_state_embedding", "loss_bc"} <= set(out.keys())
    params = list(loss.parameters())
    assert len(params) == len({id(p) for p in params})
    n_expected = sum(p.numel() for m in (actor, critic, idm) for p in m.parameters())
    assert sum(p.numel() for p in params) == n_expected
    # a2c alone accepts a plain collector batch
    a2c = make_hybrid_loss(VARIANTS["a2c"], actor, critic, None)
    assert "loss_objective" in a2c(agent).keys()
