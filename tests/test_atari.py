import pytest
import torch

pytest.importorskip("ale_py")

from torchrl.collectors import Collector  # noqa: E402
from torchrl.envs.utils import check_env_specs  # noqa: E402

from torchrl_hybrid.envs.atari import ATARI_GAMES, AtariEnv  # noqa: E402
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
    env.close()


def test_unknown_game_is_refused():
    with pytest.raises(ValueError, match="cannot load the game"):
        AtariEnv("NotAGame", 1)


def test_shared_encoder_inverse_model_trains_on_collected_atari_transitions():
    env = AtariEnv("Pong", 2, num_threads=1)
    actor, critic, enc = make_atari_actor_critic(env.n_actions)
    idm = DualInverseDynamics(enc, env.n_actions, rank=8)
    assert idm.W_s.in_features == 512 and idm.M.shape == (8, 128, 128)
    batch = next(iter(Collector(env, actor, frames_per_batch=8, total_frames=8)))
    out = DualInverseDynamicsLoss(idm, action_coeff=1.0)(batch)
    sum(v for k, v in out.items() if k.startswith("loss_")).backward()
    assert enc.convs[0].weight.grad is not None  # the shared encoder learns from the inverse model too
    env.close()
