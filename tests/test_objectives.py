import math

import pytest
import torch
import torch.nn.functional as F
from tensordict import TensorDict

from torchrl_hybrid.modules import DualInverseDynamics, MLPInverseDynamics, OneHotEncoder, make_tabular_actor_critic
from torchrl_hybrid.objectives import DualInverseDynamicsLoss, ExpertBCLoss, InverseDynamicsLoss
from torchrl_hybrid.variants import VARIANTS, make_hybrid_loss


def transitions(n=12, S=7, A=4):
    return TensorDict(
        {
            "observation": torch.randint(S, (n,)),
            "action": torch.randint(A, (n,)),
            ("next", "observation"): torch.randint(S, (n,)),
        },
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
        {
            "observation": torch.randint(7, (3, 2)),
            "action": torch.randint(4, (3, 2)),
            "next": {
                "observation": torch.randint(7, (3, 2)),
                "reward": torch.randn(3, 2, 1),
                "done": torch.zeros(3, 2, 1, dtype=torch.bool),
                "terminated": torch.zeros(3, 2, 1, dtype=torch.bool),
            },
        },
        [3, 2],
    )
    expert = transitions(5).exclude("action")
    out = loss(TensorDict({"agent": agent, "expert": expert}, []))
    assert {
        "loss_objective",
        "loss_critic",
        "loss_entropy",
        "loss_inverse",
        "loss_action_embedding",
        "loss_state_embedding",
        "loss_bc",
    } <= set(out.keys())
    params = list(loss.parameters())
    assert len(params) == len({id(p) for p in params})
    n_expected = sum(p.numel() for m in (actor, critic, idm) for p in m.parameters())
    assert sum(p.numel() for p in params) == n_expected
    # a2c alone accepts a plain collector batch
    a2c = make_hybrid_loss(VARIANTS["a2c"], actor, critic, None)
    assert "loss_objective" in a2c(agent).keys()


def _bc_setup(**kw):
    torch.manual_seed(0)
    actor, _ = make_tabular_actor_critic(7, 4)
    idm = DualInverseDynamics(OneHotEncoder(7), 4, d_state=5, d=6, rank=2)
    return actor, idm, ExpertBCLoss(actor, idm, bc_coeff=2.0, **kw), transitions()


def test_bc_soft_labels_are_the_cross_entropy_to_the_inverse_model():
    actor, idm, loss, td = _bc_setup(labels="soft")
    out = loss(td.clone())
    p_i = idm.action_logits(td["observation"], td["next", "observation"]).softmax(-1).detach()
    log_pi = actor.get_dist(td.select("observation").clone()).logits.log_softmax(-1)
    assert torch.allclose(out["loss_bc"], 2.0 * -(p_i * log_pi).sum(-1).mean(), atol=1e-6)
    # two look-alike actions with equal P_i keep equal probability under soft BC
    pair = TensorDict({"observation": torch.zeros(1, dtype=torch.long)}, [1])
    opt = torch.optim.SGD(actor.parameters(), lr=0.5)
    soft = torch.tensor([[0.5, 0.5, 0.0, 0.0]])
    for _ in range(300):
        logits = actor.get_dist(pair.clone()).logits
        loss = -(soft * logits.log_softmax(-1)).sum()
        opt.zero_grad()
        loss.backward()
        opt.step()
    probs = actor.get_dist(pair.clone()).probs[0]
    assert abs(float(probs[0] - probs[1])) < 0.02 and float(probs[:2].sum()) > 0.95


def test_bc_confidence_gate_clones_only_confident_pairs():
    actor, idm, loss, td = _bc_setup()
    p_i = idm.action_logits(td["observation"], td["next", "observation"]).softmax(-1).detach()
    conf = p_i.max(-1).values
    threshold = float(conf.median())
    gated = ExpertBCLoss(actor, idm, bc_coeff=2.0, confidence=threshold)
    out = gated(td.clone())
    keep = conf >= threshold
    logp = actor.get_dist(td.select("observation").clone()).log_prob(p_i.argmax(-1))
    assert torch.allclose(out["loss_bc"], 2.0 * -logp[keep].mean(), atol=1e-6)
    assert float(out["bc_kept"]) == pytest.approx(float(keep.float().mean()))
    nothing = ExpertBCLoss(actor, idm, bc_coeff=2.0, confidence=1.0)(td.clone())
    assert float(nothing["loss_bc"]) == 0.0 and float(nothing["bc_kept"]) == 0.0


def test_bc_entropy_floor_penalises_only_below_the_floor():
    actor, idm, plain, td = _bc_setup()
    base = plain(td.clone())
    h = actor.get_dist(td.select("observation").clone()).entropy()
    floored = ExpertBCLoss(actor, idm, bc_coeff=2.0, entropy_floor=1.5)(td.clone())
    assert torch.allclose(floored["loss_bc"], base["loss_bc"] + 2.0 * (1.5 - h).clamp_min(0).mean(), atol=1e-6)
    low = ExpertBCLoss(actor, idm, bc_coeff=2.0, entropy_floor=1e-3)(td.clone())
    assert torch.allclose(low["loss_bc"], base["loss_bc"])  # entropy is far above a tiny floor
    with pytest.raises(ValueError, match="labels='hard'"):
        ExpertBCLoss(actor, idm, labels="hard")
    with pytest.raises(ValueError, match="need an inverse model"):
        ExpertBCLoss(actor, None, labels="soft")


def test_inverse_model_ready_hook_switches_bc_on_at_the_held_out_accuracy():
    from torchrl_hybrid.trainers.hooks import InverseModelReadyHook

    actor, idm, loss, _ = _bc_setup()

    class FakeTrainer:
        collected_frames = 0

    hook = InverseModelReadyHook(loss, "bc_coeff", 2.0, accuracy=0.5, min_frames=300, smoothing=0.5)
    hook._trainer = FakeTrainer()
    assert float(loss.bc_coeff) == 0.0
    for frames, acc in [(100, 0.2), (200, 0.9), (250, 0.9)]:  # running mean 0.2, 0.55, 0.725 but < 300 frames
        FakeTrainer.collected_frames = frames
        hook(1, TensorDict({"idm_accuracy": torch.tensor(acc)}, []))
        assert float(loss.bc_coeff) == 0.0
    FakeTrainer.collected_frames = 320
    hook(1, TensorDict({"idm_accuracy": torch.tensor(0.6)}, []))
    assert float(loss.bc_coeff) == 2.0 and hook.on_at == 320
    hook(1, TensorDict({"idm_accuracy": torch.tensor(0.0)}, []))  # for good
    assert float(loss.bc_coeff) == 2.0
    other = InverseModelReadyHook(loss, "bc_coeff", 2.0, accuracy=0.5)
    assert float(loss.bc_coeff) == 0.0
    other.load_state_dict(hook.state_dict())
    assert float(loss.bc_coeff) == 2.0 and other.on_at == 320
    # with annealing: from the switch-on frame the weight falls linearly to 0 over anneal_frames
    annealed = InverseModelReadyHook(loss, "bc_coeff", 2.0, accuracy=0.5, smoothing=1.0, anneal_frames=400)
    annealed._trainer = FakeTrainer()
    for frames, acc, coeff in [(100, 0.2, 0.0), (200, 0.9, 2.0), (300, 0.0, 1.5), (500, 0.0, 0.5), (700, 0.0, 0.0)]:
        FakeTrainer.collected_frames = frames
        annealed(1, TensorDict({"idm_accuracy": torch.tensor(acc)}, []))
        assert float(loss.bc_coeff) == pytest.approx(coeff), frames
    assert annealed.on_at == 200
    resumed = InverseModelReadyHook(loss, "bc_coeff", 2.0, accuracy=0.5, anneal_frames=400)
    resumed._trainer = FakeTrainer()
    FakeTrainer.collected_frames = 300  # a checkpoint loaded at 300 frames: the weight where the schedule is
    resumed.load_state_dict(annealed.state_dict())
    assert float(loss.bc_coeff) == pytest.approx(1.5)
    with pytest.raises(ValueError, match="anneal_frames must be >= 0"):
        InverseModelReadyHook(loss, "bc_coeff", 2.0, accuracy=0.5, anneal_frames=-1)


def test_delayed_coefficient_hook_anneals_the_bc_weight_linearly_to_zero():
    from torchrl_hybrid.trainers.hooks import DelayedCoefficientHook

    _, _, loss, _ = _bc_setup()

    class FakeTrainer:
        collected_frames = 0

    hook = DelayedCoefficientHook(loss, "bc_coeff", 2.0, start_frames=100, anneal_frames=400)
    hook._trainer = FakeTrainer()
    seen = []
    for frames in (0, 99, 100, 200, 300, 500, 900):
        FakeTrainer.collected_frames = frames
        hook()
        seen.append(round(float(loss.bc_coeff), 6))
    assert seen == [0.0, 0.0, 2.0, 1.5, 1.0, 0.0, 0.0]
    constant = DelayedCoefficientHook(loss, "bc_coeff", 2.0, start_frames=100)  # the paper: stays on
    assert [constant.at(f) for f in (99, 100, 10**7)] == [0.0, 2.0, 2.0]
    with pytest.raises(ValueError, match="anneal_frames must be >= 0"):
        DelayedCoefficientHook(loss, "bc_coeff", 2.0, 100, anneal_frames=-1)


def test_coefficients_are_schedulable_buffers_and_losses_are_not_functional():
    from torchrl_hybrid.objectives import PolicyEntropyLoss

    actor, _ = make_tabular_actor_critic(7, 4)
    idm = DualInverseDynamics(OneHotEncoder(7), 4, d_state=5, d=6)
    losses = {
        "action_coeff": DualInverseDynamicsLoss(idm),
        "embedding_coeff": DualInverseDynamicsLoss(idm),
        "bc_coeff": ExpertBCLoss(actor, idm),
        "entropy_coeff": PolicyEntropyLoss(actor),
    }
    for name, loss in losses.items():
        buf = getattr(loss, name)
        setattr(loss, name, 0.25)  # TorchRL's convention: an in-place update of the buffer
        assert getattr(loss, name) is buf and float(buf) == 0.25 and name in dict(loss.named_buffers())
        assert loss.functional is False
    # plain submodules: the loss trains the very parameters the caller holds
    assert losses["bc_coeff"].inverse_model is idm and losses["bc_coeff"].actor_network is actor
    assert {id(p) for p in losses["action_coeff"].parameters()} == {id(p) for p in idm.parameters()}


def test_hooks_refuse_a_coefficient_that_is_not_schedulable():
    from torchrl.objectives import LossModule

    from torchrl_hybrid.trainers.hooks import DelayedCoefficientHook

    class Plain(LossModule):
        def __init__(self):
            super().__init__()
            self.register_coeff_buffer("w", 1.0)

    with pytest.raises(ValueError, match="_schedulable_buffers"):
        DelayedCoefficientHook(Plain(), "w", 1.0, 10)
    with pytest.raises(ValueError, match="no coefficient buffer 'nope'"):
        DelayedCoefficientHook(Plain(), "nope", 1.0, 10)
    actor, _ = make_tabular_actor_critic(7, 4)
    bc = ExpertBCLoss(actor, DualInverseDynamics(OneHotEncoder(7), 4, d_state=5, d=6), bc_coeff=2.0)
    DelayedCoefficientHook(bc, "bc_coeff", 2.0, 10)
    assert float(bc.bc_coeff) == 0.0


def test_a_tensordict_module_wrapped_inverse_model_is_accepted_and_names_its_keys():
    from tensordict.nn import TensorDictModule

    idm = DualInverseDynamics(OneHotEncoder(7), 4, d_state=5, d=6)
    wrapped = TensorDictModule(idm, in_keys=["s", "s_next"], out_keys=["idm_logits"])
    td = transitions()
    td2 = TensorDict({"s": td["observation"], "s_next": td["next", "observation"], "action": td["action"]}, [12])
    plain, via = DualInverseDynamicsLoss(idm)(td), DualInverseDynamicsLoss(wrapped)(td2)
    for k in plain.keys():
        assert torch.equal(plain[k], via[k]), k
    actor, _ = make_tabular_actor_critic(7, 4)
    bc = ExpertBCLoss(actor, wrapped)
    assert bc.inverse_model is idm and bc.tensor_keys.next_observation == "s_next"
    with pytest.raises(TypeError, match="TensorDictModule wrapping one"):
        InverseDynamicsLoss(torch.nn.Linear(3, 4))
    with pytest.raises(ValueError, match="exactly two in_keys"):
        InverseDynamicsLoss(TensorDictModule(idm, in_keys=["s"], out_keys=["x"]))


def test_prior_corrected_labels_undo_the_inverse_models_echo_of_the_agents_policy():
    """A known case: from state 0, (s, s') is twice as likely under action 1 as under action 0
    (P(s'|s,a) = [1, 2]), but the agent takes action 0 90 % of the time, so an inverse model
    fitted to its transitions says P_i = [0.9, 0.2] / 1.1: the paper's label is action 0, the
    agent's own favourite. Divided by pi and renormalised, P_i = [1, 2] / 3: action 1."""
    from tensordict.nn import TensorDictModule
    from torch import nn
    from torchrl.modules import ProbabilisticActor

    from torchrl_hybrid.modules.inverse_dynamics import InverseDynamicsModel

    pi = torch.tensor([0.9, 0.1])
    head = nn.Linear(1, 2)
    with torch.no_grad():
        head.weight.zero_()
        head.bias.copy_(pi.log())
    actor = ProbabilisticActor(
        TensorDictModule(head, in_keys=["observation"], out_keys=["logits"]),
        in_keys=["logits"],
        distribution_class=torch.distributions.Categorical,
    )

    class Echo(InverseDynamicsModel):  # P_i = P(s'|s,a) pi(a|s), normalised
        def __init__(self):
            nn.Module.__init__(self)
            self.n_actions = 2

        def action_logits(self, obs, next_obs):
            p = torch.tensor([1.0, 2.0]) * pi
            return (p / p.sum()).log().expand(obs.shape[0], 2)

    td = TensorDict({"observation": torch.zeros(4, 1), ("next", "observation"): torch.ones(4, 1)}, [4])
    paper = ExpertBCLoss(actor, Echo(), bc_coeff=1.0)
    paper(td)
    assert td["inferred_action"].tolist() == [0, 0, 0, 0]
    corrected = ExpertBCLoss(actor, Echo(), bc_coeff=1.0, prior_floor=0.05)
    out = corrected(td)
    assert td["inferred_action"].tolist() == [1, 1, 1, 1]
    assert float(out["loss_bc"]) == pytest.approx(-math.log(0.1), rel=1e-5)  # cloning action 1 under pi
    soft = ExpertBCLoss(actor, Echo(), bc_coeff=1.0, labels="soft", prior_floor=0.05)(td)
    expected = -(torch.tensor([1 / 3, 2 / 3]) * pi.log()).sum()
    assert float(soft["loss_bc"]) == pytest.approx(float(expected), rel=1e-5)
    # the floor bounds the boost of an action the policy almost never takes
    assert ExpertBCLoss(actor, Echo(), prior_floor=0.5).prior_floor == 0.5
    with pytest.raises(ValueError, match="prior_floor=1.5 must be in"):
        ExpertBCLoss(actor, Echo(), prior_floor=1.5)
    with pytest.raises(ValueError, match="need an inverse model"):
        ExpertBCLoss(actor, None, prior_floor=0.05)


def test_explorer_slots_give_the_inverse_model_every_action_and_stay_out_of_the_rl_loss():
    """A known case: s' = (s + a) mod 10 with 3 actions, and an agent whose policy has
    collapsed onto action 0. On its own transitions the inverse model can only learn label 0
    (its prior is the agent's policy); with 4 of 8 env slots acting uniformly at random
    (ExplorerSlots) it labels every action right. The RL loss never sees the explorer slots."""
    from tensordict.nn import TensorDictModule
    from torch import nn
    from torchrl.modules import ProbabilisticActor

    from torchrl_hybrid.modules import ExplorerSlots
    from torchrl_hybrid.objectives import HybridLoss

    head = nn.Linear(1, 3)
    with torch.no_grad():
        head.weight.zero_()
        head.bias.copy_(torch.tensor([20.0, 0.0, 0.0]))  # always action 0
    actor = ProbabilisticActor(
        TensorDictModule(head, in_keys=["x"], out_keys=["logits"]),
        in_keys=["logits"],
        distribution_class=torch.distributions.Categorical,
        return_log_prob=True,
    )
    explorer = ExplorerSlots(actor, n_actions=3, n_explorers=4)

    def batch(policy, n_envs=8, steps=64):
        s = torch.randint(10, (n_envs, steps))
        td = TensorDict({"x": torch.zeros(n_envs, steps, 1)}, [n_envs, steps])
        out = torch.stack([policy(td[:, t].clone()) for t in range(steps)], 1)
        a = out["action"]
        return TensorDict(
            {
                "observation": s,
                "action": a,
                ("next", "observation"): (s + a) % 10,
                **({"explore": out["explore"]} if "explore" in out.keys() else {}),
            },
            [n_envs, steps],
        )

    torch.manual_seed(0)
    td = batch(explorer)
    assert td["explore"][:4].all() and not td["explore"][4:].any()
    assert (td["action"][4:] == 0).all()
    counts = torch.bincount(td["action"][:4].reshape(-1), minlength=3).float() / td["action"][:4].numel()
    assert torch.allclose(counts, torch.full((3,), 1 / 3), atol=0.08)  # uniform in the explorer slots

    def labels_after_training(policy):
        torch.manual_seed(1)
        data = batch(policy, steps=128).reshape(-1)  # the transitions the collector would give
        idm = DualInverseDynamics(OneHotEncoder(10), n_actions=3, d_state=16, d=16)
        loss = DualInverseDynamicsLoss(idm, embedding_coeff=0.0)
        opt = torch.optim.Adam(idm.parameters(), lr=0.05)
        for _ in range(100):
            opt.zero_grad()
            out = loss(data)
            sum(v for k, v in out.items() if k.startswith("loss")).backward()
            opt.step()
        s = torch.arange(30) % 10
        a = torch.arange(30) // 10  # every action, each state
        return float((idm.infer(s, (s + a) % 10) == a).float().mean())

    assert labels_after_training(actor) < 0.4  # the echo: action 0 everywhere (1/3 right)
    assert labels_after_training(explorer) > 0.95  # every action told apart
    # the RL loss's input drops the explorer rows, whole env rows so the returns stay per trajectory
    hybrid = HybridLoss(PolicyEntropyLossStub(), None, None)
    hybrid.forward_parts(TensorDict({"agent": td, "expert": TensorDict({}, [0])}, []))
    assert hybrid.rl_loss.seen.shape == (4, 64) and not hybrid.rl_loss.seen["explore"].any()


def test_a_minibatch_of_explorer_transitions_only_gives_a_zero_rl_loss_with_no_gradient():
    """PPO's minibatches are random rows: one may hold explorer transitions only (ClipPPOLoss
    failed on the empty rest). Its RL terms are then 0, with their keys, and no gradient."""
    from tensordict.nn import TensorDictModule
    from torchrl.modules import ProbabilisticActor, ValueOperator
    from torchrl.objectives import ClipPPOLoss

    from torchrl_hybrid.objectives import HybridLoss

    torch.manual_seed(0)
    actor_net = torch.nn.Linear(4, 3)
    actor = ProbabilisticActor(
        TensorDictModule(actor_net, ["observation"], ["logits"]),
        in_keys=["logits"],
        distribution_class=torch.distributions.Categorical,
        return_log_prob=True,
    )
    critic = ValueOperator(torch.nn.Linear(4, 1), in_keys=["observation"])
    ppo = ClipPPOLoss(actor, critic)
    n = 8
    td = TensorDict(
        {
            "observation": torch.randn(n, 4),
            "action": torch.randint(0, 3, (n,)),
            "action_log_prob": torch.full((n,), -1.1),
            "advantage": torch.randn(n, 1),
            "value_target": torch.randn(n, 1),
            "explore": torch.ones(n, 1, dtype=torch.bool),
        },
        [n],
    )
    parts = HybridLoss(ppo, None, None).forward_parts(TensorDict({"agent": td, "expert": TensorDict({}, [0])}, []))
    rl = parts["rl"]
    assert {"loss_objective", "loss_critic", "loss_entropy"} <= set(rl.keys())
    total = sum(v for k, v in rl.items() if k.startswith("loss_"))
    assert total.item() == 0.0 and total.requires_grad
    total.backward()
    assert all(p.grad is None or not p.grad.any() for p in ppo.parameters())
    td["explore"][:2] = False  # two policy rows: the loss is theirs, not zero
    rl = HybridLoss(ppo, None, None).forward_parts(TensorDict({"agent": td, "expert": TensorDict({}, [0])}, []))["rl"]
    assert rl["loss_critic"].item() != 0.0


class PolicyEntropyLossStub(torch.nn.Module):
    """Records the batch the RL part of a HybridLoss is given."""

    def forward(self, td):
        self.seen = td
        return TensorDict({"loss_objective": torch.zeros(())}, [])
