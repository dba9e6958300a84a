import pytest
import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, ReplayBuffer

from torchrl_hybrid.data import (
    EXPERT_ACTION_KEY,
    CurriculumSampler,
    VisitedStateSampler,
    apply_demo_noise,
    load_demos,
    make_expert_buffer,
    pairs_from_trajectories,
    save_demos,
    tabular_state_pairs,
    tabular_trajectories,
)


def test_pairs_never_span_two_trajectories():
    trajs = [torch.tensor([0, 1, 2]), torch.tensor([10, 11, 12, 13]), torch.tensor([5])]
    td = pairs_from_trajectories(trajs)
    assert td["observation"].tolist() == [0, 1, 10, 11, 12]
    assert td["next", "observation"].tolist() == [1, 2, 11, 12, 13]
    assert td["step"].tolist() == [0, 1, 0, 1, 2]
    assert td["trajectory"].tolist() == [0, 0, 1, 1, 1]


def test_expert_demos_cover_every_state_with_true_transitions(taxi):
    model, policy, _ = taxi
    d = tabular_state_pairs(model, policy)
    assert d.numel() == 500 and torch.equal(d["observation"], torch.arange(500))
    assert torch.equal(d["next", "observation"], model.next_state[d["observation"], d[EXPERT_ACTION_KEY], 0])
    t = tabular_trajectories(model, policy, 10, generator=torch.Generator().manual_seed(0))
    assert (t["step"] == 0).sum() == 10


@pytest.mark.parametrize("eta,epsilon", [(0.25, 0.0), (0.5, 0.1), (0.75, 0.3), (0.0, 0.2)])
def test_noise_fractions_are_exact(taxi, eta, epsilon):
    model, policy, optimal = taxi
    d = tabular_state_pairs(model, policy)
    g = torch.Generator().manual_seed(3)
    n = apply_demo_noise(d, model, optimal, eta=eta, epsilon=epsilon, generator=g)
    kept = int(500 - int(eta * 500))
    assert n.numel() == kept and len(torch.unique(n["observation"])) == kept
    if epsilon:
        bad = n["corrupted"]
        assert int(bad.sum()) == int(epsilon * kept)
        s, a = n["observation"], n[EXPERT_ACTION_KEY]
        assert not optimal[s[bad], a[bad]].any() and optimal[s[~bad], a[~bad]].all()
        assert torch.equal(n["next", "observation"], model.next_state[s, a, 0])
    # seeded: the same generator seed gives the same demos
    again = apply_demo_noise(d, model, optimal, eta=eta, epsilon=epsilon, generator=torch.Generator().manual_seed(3))
    assert torch.equal(n["observation"], again["observation"])


@pytest.mark.parametrize("kw", [{"eta": 1.0}, {"eta": -0.1}, {"epsilon": 1.0}, {"epsilon": 2}])
def test_noise_ratio_out_of_range(taxi, kw):
    model, policy, optimal = taxi
    with pytest.raises(ValueError, match="must be in \\[0, 1\\)"):
        apply_demo_noise(tabular_state_pairs(model, policy), model, optimal, **kw)


def test_curriculum_sampler_and_state_dict():
    sampler = CurriculumSampler(k0=2, frames_per_step=100)
    rb = ReplayBuffer(storage=LazyTensorStorage(40), sampler=sampler)
    rb.extend(TensorDict({"step": torch.arange(20).repeat(2)}, [40]))
    assert set(rb.sample(500)["step"].tolist()) == {0, 1}
    sampler.update(frames=250)
    assert sampler.k == 4 and set(rb.sample(500)["step"].tolist()) == {0, 1, 2, 3}
    clone = CurriculumSampler()
    clone.load_state_dict(sampler.state_dict())
    assert clone.k == 4 and clone.frames == 250 and clone.frames_per_step == 100
    empty = ReplayBuffer(storage=LazyTensorStorage(4), sampler=CurriculumSampler(k0=1))
    empty.extend(TensorDict({"step": torch.full((4,), 5)}, [4]))
    with pytest.raises(RuntimeError, match="no expert pair"):
        empty.sample(2)
    with pytest.raises(ValueError):
        CurriculumSampler(k0=0)


def test_visited_state_sampler_picks_pairs_at_visited_states(taxi):
    model, policy, _ = taxi
    demos = tabular_state_pairs(model, policy)[100:]  # states 0..99 have no pair
    sampler = VisitedStateSampler(500)
    rb = make_expert_buffer(demos, sampler=sampler, batch_size=32)
    sampler.observe(torch.tensor([[5, 150], [150, 499]]))
    batch = rb.sample()
    assert batch["observation"].tolist() == [150, 150, 499]
    assert EXPERT_ACTION_KEY not in batch.keys()


def test_buffer_drops_expert_actions_unless_asked(taxi):
    model, policy, _ = taxi
    demos = tabular_state_pairs(model, policy)
    assert EXPERT_ACTION_KEY not in make_expert_buffer(demos, batch_size=4).sample().keys()
    assert EXPERT_ACTION_KEY in make_expert_buffer(demos, batch_size=4, include_expert_actions=True).sample().keys()


def test_demo_files_round_trip_and_validation(tmp_path, taxi):
    model, policy, _ = taxi
    demos = tabular_state_pairs(model, policy)
    save_demos(demos, tmp_path / "ok", {"env_id": "Taxi-v4"})
    loaded, meta = load_demos(tmp_path / "ok", obs_shape=(), obs_dtype=torch.long)
    assert meta["env_id"] == "Taxi-v4" and torch.equal(loaded["observation"], demos["observation"])
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_demos(tmp_path / "missing")
    save_demos(demos[:0], tmp_path / "empty")
    with pytest.raises(ValueError, match="empty"):
        load_demos(tmp_path / "empty")
    with pytest.raises(ValueError, match="observation shape"):
        load_demos(tmp_path / "ok", obs_shape=(4, 84, 84))
    img = TensorDict({"observation": torch.rand(3, 2), ("next", "observation"): torch.rand(3, 2)}, [3])
    img["observation"][1, 0] = float("nan")
    save_demos(img, tmp_path / "nan")
    with pytest.raises(ValueError, match="NaN"):
        load_demos(tmp_path / "nan")


def test_authors_noise_mode_redraws_with_random_moves(taxi):
    model, policy, optimal = taxi
    d = tabular_state_pairs(model, policy)
    n = apply_demo_noise(
        d, model, optimal, epsilon=0.3, epsilon_mode="authors", generator=torch.Generator().manual_seed(0)
    )
    bad = n["corrupted"]
    assert 100 < int(bad.sum()) < 200  # about 30 % of 500, drawn per pair
    assert set(n[EXPERT_ACTION_KEY][bad].tolist()) <= {0, 1, 2, 3}
    assert torch.equal(n["next", "observation"], model.next_state[n["observation"], n[EXPERT_ACTION_KEY], 0])
    with pytest.raises(ValueError, match="epsilon_mode"):
        apply_demo_noise(d, model, optimal, epsilon=0.1, epsilon_mode="typo")
