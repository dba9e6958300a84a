import copy
import pickle

import pytest
import torch

from torchrl_hybrid.modules import DualInverseDynamics, MLPInverseDynamics, OneHotEncoder


def small_dual(rank=3, n_states=None):
    return DualInverseDynamics(OneHotEncoder(7), n_actions=4, d_state=5, d=6, rank=rank, n_states=n_states)


def test_dual_model_equals_the_explicit_tensor_formula():
    idm = small_dual()
    s, s2, a = torch.tensor([0, 3, 6]), torch.tensor([1, 3, 2]), torch.tensor([2, 0, 3])
    T = torch.zeros(5, 6, 6)  # d_s x d_a x d_ds
    for r in range(idm.rank):
        for k in range(6):
            T[:, k, :] += torch.outer(idm.M[r][:, k], idm.N[r][:, k])
    assert torch.allclose(T, idm.full_tensor(), atol=1e-6)
    terms = idm.terms(s, a, s2)
    h_s, h_ds = idm.embed(s, s2)
    h_a = idm.action_embedding(a)
    score = torch.einsum("bi,ikj,bk,bj->b", h_s, T, h_a, h_ds)
    assert torch.allclose(idm.score(s, a, s2), score, atol=1e-5)
    # both predictions contract the same tensor over its first and last slots
    assert torch.allclose(terms["h_a_hat"], torch.einsum("bi,ikj,bj->bk", h_s, T, h_ds), atol=1e-5)
    assert torch.allclose(terms["h_ds_hat"], torch.einsum("bi,ikj,bj->bk", h_s, T, h_a), atol=1e-5)
    assert torch.allclose(terms["action_logits"], idm.action_head(terms["h_a_hat"]))
    # h_ds = W_ds (h_s' - h_s), h_s = W_s one_hot(s)
    assert torch.allclose(h_s, idm.W_s.weight[:, s].T)
    assert torch.allclose(h_ds, idm.W_ds(idm.W_s.weight[:, s2].T - idm.W_s.weight[:, s].T), atol=1e-6)


def test_forward_score_is_not_the_score_because_T_is_not_symmetric():
    # the docstring's claim: <h_ds, F(s, a)> = T x1 h_s x2 h_ds x3 h_a, which is the score
    # T x1 h_s x2 h_a x3 h_ds only where T[:, k, j] = T[:, j, k]; the shared M_r, N_r do not make it so
    torch.manual_seed(0)
    idm = small_dual()
    s, s2, a = torch.tensor([0, 3, 6]), torch.tensor([1, 3, 2]), torch.tensor([2, 0, 3])
    T = idm.full_tensor()
    h_s, h_ds = idm.embed(s, s2)
    h_a = idm.action_embedding(a)
    assert torch.allclose(idm.forward_score(s, a, s2), torch.einsum("bi,ikj,bk,bj->b", h_s, T, h_ds, h_a), atol=1e-5)
    assert not torch.allclose(idm.forward_score(s, a, s2), idm.score(s, a, s2), atol=1e-3)
    assert not torch.allclose(T, T.transpose(1, 2), atol=1e-3)
    # N_r = I makes T[i, k, j] = sum_r M_r[i, k] [j == k] symmetric in k, j: then the two views agree
    with torch.no_grad():
        idm.N.copy_(torch.eye(6).expand(idm.rank, 6, 6))
    T = idm.full_tensor()
    assert torch.allclose(T, T.transpose(1, 2))
    assert torch.allclose(idm.forward_score(s, a, s2), idm.score(s, a, s2), atol=1e-5)


def test_both_directions_share_the_same_factors():
    idm = small_dual()
    names = [n for n, _ in idm.named_parameters()]
    assert names.count("M") == 1 and names.count("N") == 1
    s, s2, a = torch.tensor([0, 1]), torch.tensor([2, 3]), torch.tensor([1, 2])
    for key in ("h_a_hat", "h_ds_hat"):
        idm.zero_grad()
        idm.terms(s, a, s2)[key].sum().backward()
        assert idm.M.grad.abs().sum() > 0 and idm.N.grad.abs().sum() > 0


def test_forward_head_and_shapes():
    idm = small_dual(n_states=7)
    out = idm.terms(torch.tensor([0, 1]), torch.tensor([1, 2]), torch.tensor([2, 3]))
    assert out["next_state_logits"].shape == (2, 7)
    assert idm.infer(torch.tensor([0]), torch.tensor([1])).shape == (1,)
    mlp = MLPInverseDynamics(OneHotEncoder(7), n_actions=4, d_state=5, hidden=8)
    assert mlp.action_logits(torch.tensor([0, 1]), torch.tensor([2, 3])).shape == (2, 4)


def test_paper_parameter_count_of_the_taxi_model():
    idm = DualInverseDynamics(OneHotEncoder(500), 6, rank=2)
    assert idm.M.numel() + idm.N.numel() == 128 * 128 * 2 * 2
    ratio = (idm.M.numel() + idm.N.numel()) / (500 * 6 * 500)
    assert round(100 * ratio, 2) == 4.37


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="rank"):
        small_dual(rank=0)
    with pytest.raises(ValueError, match="num_layers"):
        MLPInverseDynamics(OneHotEncoder(7), 4, num_layers=0)


def test_compiled_atari_cnn_gives_the_plain_numbers():
    """encoder.compile_cnn() (AtariConfig.compile): the same features and gradients as the
    plain modules, for the batch sizes of collection (16) and of the learner (80)."""
    from torchrl_hybrid.modules import AtariEncoder

    torch.manual_seed(0)
    plain = AtariEncoder()
    plain.reuse_features = False
    compiled = copy.deepcopy(plain).compile_cnn("default")
    for n in (16, 80):
        frames = torch.randint(0, 256, (n, 4, 84, 84), dtype=torch.uint8)
        a, b = plain(frames), compiled(frames)
        torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-5)
        a.square().sum().backward()
        b.square().sum().backward()
        for (name, p), q in zip(plain.named_parameters(), compiled.parameters()):
            torch.testing.assert_close(q.grad, p.grad, rtol=1e-4, atol=1e-5, msg=name)
            p.grad = q.grad = None
    # a copy (deepcopy, a worker collector's pickled policy) is compiled again, in the same mode
    for twin in (copy.deepcopy(compiled), pickle.loads(pickle.dumps(compiled))):
        assert twin.compile_mode == "default" and twin._compiled is not None
        assert twin._compiled is not compiled._compiled  # its own, compiled for its own weights
    assert compiled.compile_cnn("off")._compiled is None
    assert copy.deepcopy(compiled)._compiled is None
    with pytest.raises(ValueError, match="compile='fast'"):
        plain.compile_cnn("fast")
