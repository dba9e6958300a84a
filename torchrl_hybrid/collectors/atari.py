"""A lean synchronous collector for ale-py's vector envs, on CPU or CUDA.

TorchRL's generic :class:`~torchrl.collectors.Collector` builds several
TensorDicts per env step (env step, transforms, policy call, step_mdp) and
copies every step into its rollout buffer. On Atari, where a step of 16 games
takes a few milliseconds, that plumbing costs as much as the games themselves.
:class:`AtariCollector` produces the same batches (same keys, same ``[envs,
time]`` layout, same TorchRL semantics for final observations) from plain
tensors: the policy reads each step's frames straight from the batch buffer,
and each frame stack is copied once, as uint8, to the policy's device (through
pinned memory and a non-blocking copy on CUDA).

With ``env_groups`` > 1 the games are split into groups, each an ale-py vector
env with its own worker threads, stepped as a pipeline: while one group's games
step, the policy runs on the frames of another. Every action is still sampled
from the current policy on the current frames (the weights change only between
batches), so this is synchronous A2C, with the same data: greedy collection gives
bit-identical batches for any ``env_groups`` (tested), sampled collection draws
from the same distributions with a different order of random numbers.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterator, Sequence

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.collectors import BaseCollector
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_hybrid.envs.atari import AtariEnv

__all__ = ["AtariCollector"]


class _Staging:
    """Host-side copy of one env group's newest frames, pinned on CUDA so the copy
    to the device is asynchronous. Each group's buffer is rewritten only after that
    group's actions came back to the host, which waits for the previous copy."""

    def __init__(self, shape, device: torch.device):
        self.cuda = device.type == "cuda"
        self.buf = torch.empty(shape, dtype=torch.uint8, pin_memory=True) if self.cuda else None

    def to_device(self, frames: np.ndarray, *dsts: torch.Tensor) -> None:
        src = torch.from_numpy(frames)
        if self.cuda:
            self.buf.copy_(src)
            src = self.buf
        for dst in dsts:
            dst.copy_(src, non_blocking=self.cuda)


class AtariCollector(BaseCollector):
    """Collects ``[num_envs, n_steps]`` batches from one or more :class:`AtariEnv`.

    Args:
        envs: an :class:`AtariEnv`, or a list of them stepped as a pipeline (their
            games are concatenated in order along the env dimension; make them with
            :meth:`AtariCollector.make_envs` to keep each game's seed as in one env).
        policy: maps a ``[n, stack, 84, 84]`` uint8 tensor to ``(action [n],
            action_log_prob [n], state_value [n, 1])``, e.g.
            :class:`~torchrl_hybrid.modules.AtariCollectionPolicy`, or a
            ``TensorDictModule`` wrapping one.

    Keyword Args:
        frames_per_batch: agent steps per batch; a multiple of the number of games.
        total_frames: agent steps in all (``-1``: endless).
        device: where the batches and the policy's inputs live (``"cpu"`` or ``"cuda"``).
        exploration_type: the policy samples under TorchRL's ``RANDOM`` (default, as
            TorchRL's collectors); ``DETERMINISTIC`` takes the most likely action.
        keep_features: run the policy's encoder with autograd on during collection
            and hand the batch's features, with their graph, to the encoder's cache
            (:meth:`~torchrl_hybrid.modules.AtariEncoder.remember`), so that the
            learner's forward pass over the batch's observations is not run again.
            Exact for one update per batch (the weights the features were computed
            with are the weights the loss differentiates; a weight change makes the
            encoder ignore them). Needs a policy with ``encoder`` and ``heads``
            (:class:`~torchrl_hybrid.modules.AtariCollectionPolicy`).

    Each batch holds ``observation``, ``action``, ``action_log_prob``,
    ``state_value`` and, under ``"next"``, ``observation`` (the true last frame
    stack where an episode ended), ``reward`` (clipped if the env clips),
    ``score`` (raw), ``episode_score`` (running sum of ``score``), ``lives``,
    ``done``, ``terminated``, ``truncated``: what TorchRL's ``Collector`` gives
    for a ``TransformedEnv(AtariEnv, RewardSum(in_keys=["score"],
    out_keys=["episode_score"]))`` with the same policy.

    Examples:
        >>> from torchrl_hybrid.modules import make_atari_actor_critic
        >>> envs = AtariCollector.make_envs("Pong", 4, groups=2)
        >>> *_, policy = make_atari_actor_critic(envs[0].n_actions)
        >>> collector = AtariCollector(envs, policy, frames_per_batch=8, total_frames=16)
        >>> [b.shape for b in collector]
        [torch.Size([4, 2]), torch.Size([4, 2])]
    """

    def __init__(
        self,
        envs: AtariEnv | Sequence[AtariEnv],
        policy: nn.Module,
        *,
        frames_per_batch: int,
        total_frames: int = -1,
        device: str | torch.device = "cpu",
        exploration_type: ExplorationType = ExplorationType.RANDOM,
        keep_features: bool = False,
    ):
        super().__init__()
        self.envs = [envs] if isinstance(envs, AtariEnv) else list(envs)
        if not self.envs:
            raise ValueError("AtariCollector needs at least one AtariEnv")
        games = {(e.game, tuple(sorted(e.preprocessing.items()))) for e in self.envs}
        if len(games) > 1:
            raise ValueError("AtariCollector: every env group must play the same game with the same preprocessing")
        self.n_actions = self.envs[0].n_actions
        self.num_envs = sum(e.batch_size[0] for e in self.envs)
        if frames_per_batch < self.num_envs or frames_per_batch % self.num_envs:
            raise ValueError(
                f"frames_per_batch={frames_per_batch} must be a positive multiple of the number of "
                f"games ({self.num_envs})"
            )
        self.policy = policy
        self._policy_fn = (
            policy.module if isinstance(policy, TensorDictModuleBase) and hasattr(policy, "module") else policy
        )
        try:  # the fused policy's action head; for any other module its last linear layer
            self.envs[0].check_policy(getattr(self._policy_fn, "policy_head", self._policy_fn))
        except ValueError:
            for env in self.envs:
                env.close()
            raise
        if keep_features and not (
            hasattr(self._policy_fn, "encoder")
            and hasattr(self._policy_fn, "heads")
            and hasattr(self._policy_fn.encoder, "remember")
        ):
            raise ValueError(
                "keep_features=True needs a policy with `encoder` (an AtariEncoder) and `heads`, "
                "such as AtariCollectionPolicy"
            )
        self.keep_features = bool(keep_features)
        self.frames_per_batch = int(frames_per_batch)
        self.n_steps = self.frames_per_batch // self.num_envs
        self.requested_frames_per_batch = self.frames_per_batch  # read by BaseCollector
        self.total_frames = int(total_frames) if total_frames > 0 else -1
        self.init_random_frames = 0
        self.device = torch.device(device)
        self.exploration_type = exploration_type
        self.reward_clipping = self.envs[0].reward_clipping
        stack_shape = tuple(self.envs[0].observation_spec["observation"].shape[1:])
        self._stack_shape = stack_shape
        bounds = np.cumsum([0] + [e.batch_size[0] for e in self.envs])
        self._slices = [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]
        self._staging = [_Staging((s.stop - s.start, *stack_shape), self.device) for s in self._slices]
        self._frames = 0
        self._obs: torch.Tensor | None = None  # [num_envs, *stack] frames the next batch starts from
        self._episode_score = torch.zeros(self.num_envs, dtype=torch.float64)
        self._closed = False
        self._start()  # as TorchRL's collectors: the envs are reset when the collector is built

    @staticmethod
    def make_envs(game: str, num_envs: int, *, groups: int = 1, seed: int = 0, **env_kwargs) -> list[AtariEnv]:
        """``groups`` :class:`AtariEnv` of ``num_envs / groups`` games each, seeded so
        that game ``i`` gets seed ``seed + i`` as it would in one env of ``num_envs``."""
        if groups < 1 or num_envs % groups:
            raise ValueError(f"env_groups={groups} must divide num_envs={num_envs}")
        n = num_envs // groups
        return [AtariEnv(game, n, seed=seed + g * n, **env_kwargs) for g in range(groups)]

    # -- collection -----------------------------------------------------------
    def _start(self) -> None:
        self._obs = torch.empty(self.num_envs, *self._stack_shape, dtype=torch.uint8, device=self.device)
        for env, sl, stage in zip(self.envs, self._slices, self._staging):
            obs, _ = env.reset_all()
            stage.to_device(obs, self._obs[sl])
        self._episode_score.zero_()

    def rollout(self) -> TensorDictBase:
        """Collects one batch."""
        with torch.no_grad(), set_exploration_type(self.exploration_type):
            return self._rollout()

    def _policy_step(self, frames: torch.Tensor, feats_out: list):
        if not self.keep_features:
            return self._policy_fn(frames)
        with torch.enable_grad():
            feats = self._policy_fn.encoder(frames)
        feats_out.append(feats)
        return self._policy_fn.heads(feats.detach())

    def _rollout(self) -> TensorDictBase:
        if self._obs is None:
            self._start()
        N, T, dev = self.num_envs, self.n_steps, self.device
        obs = torch.empty(N, T, *self._stack_shape, dtype=torch.uint8, device=dev)
        next_obs = torch.empty_like(obs)
        obs[:, 0] = self._obs
        action = torch.empty(N, T, dtype=torch.int64, device=dev)
        log_prob = torch.empty(N, T, device=dev)
        value = torch.empty(N, T, 1, device=dev)
        # small per-step results stay on the host and travel once per batch
        score = np.empty((N, T), dtype=np.float32)
        term = np.empty((N, T), dtype=bool)
        trunc = np.empty((N, T), dtype=bool)
        lives = np.empty((N, T), dtype=np.int64)
        finals = []  # (t, first env of the group, envs that ended, their final frames)
        feats = [[] for _ in self.envs]  # keep_features: per group, per step

        def act_and_send(g: int, t: int) -> None:
            sl = self._slices[g]
            a, lp, v = self._policy_step(obs[sl, t], feats[g])
            action[sl, t], log_prob[sl, t], value[sl, t] = a, lp, v
            self.envs[g].send(a.cpu())

        def receive(g: int, t: int) -> None:
            sl = self._slices[g]
            o, sc, te, tr, final, lv = self.envs[g].recv()
            score[sl, t], term[sl, t], trunc[sl, t], lives[sl, t] = sc, te, tr, lv
            if t + 1 < T:
                self._staging[g].to_device(o, next_obs[sl, t], obs[sl, t + 1])
            else:
                self._staging[g].to_device(o, next_obs[sl, t], self._obs[sl])
            if final is not None:
                done = np.flatnonzero(te | tr)
                finals.append((t, sl.start, done, final[done]))

        groups = range(len(self.envs))
        for g in groups:
            act_and_send(g, 0)
        for t in range(T):
            for g in groups:  # while group g's games step, the policy serves the next group
                receive(g, t)
                if t + 1 < T:
                    act_and_send(g, t + 1)

        if self.keep_features:
            with torch.enable_grad():  # the stacked features keep their graph
                per_group = [torch.stack(f, dim=1) for f in feats]  # [n_g, T, d]
                self._policy_fn.encoder.remember(obs, torch.cat(per_group) if len(per_group) > 1 else per_group[0])
        # the true last frame stack of each ended episode (the row holds the new episode's first)
        for t, start, done, frames in finals:
            rows = torch.from_numpy(done + start).to(dev)
            next_obs[rows, t] = torch.from_numpy(np.ascontiguousarray(frames)).to(dev)
        score_t = torch.from_numpy(score)
        done_np = term | trunc
        # running episode score (what TorchRL's RewardSum writes), restarted after each end
        ep = np.empty((N, T), dtype=np.float64)
        run = self._episode_score.numpy()
        for t in range(T):
            run += score[:, t]
            ep[:, t] = run
            run[done_np[:, t]] = 0.0
        self._frames += N * T
        host = {
            "reward": (score_t.sign() if self.reward_clipping else score_t).unsqueeze(-1),
            "score": score_t.unsqueeze(-1),
            "episode_score": torch.from_numpy(ep.astype(np.float32)).unsqueeze(-1),
            "lives": torch.from_numpy(lives).unsqueeze(-1),
            "done": torch.from_numpy(done_np).unsqueeze(-1),
            "terminated": torch.from_numpy(term).unsqueeze(-1),
            "truncated": torch.from_numpy(trunc).unsqueeze(-1),
        }
        if dev.type != "cpu":
            host = {k: v.pin_memory().to(dev, non_blocking=True) for k, v in host.items()}
        nxt = TensorDict({"observation": next_obs, **host}, [N, T], device=dev)
        return TensorDict(
            {"observation": obs, "action": action, "action_log_prob": log_prob, "state_value": value, "next": nxt},
            [N, T],
            device=dev,
        )

    def iterator(self) -> Iterator[TensorDictBase]:
        while self.total_frames < 0 or self._frames < self.total_frames:
            yield self.rollout()

    # -- TorchRL collector API --------------------------------------------------
    def update_policy_weights_(self, *args, **kwargs) -> None:
        """The policy is the learner's own module (same process, same device): nothing to copy."""

    def set_seed(self, seed: int, static_seed: bool = False) -> int:
        for env, sl in zip(self.envs, self._slices):
            env.set_seed(seed + sl.start)
        self._obs = None  # the next batch starts new episodes with the new seeds
        return seed

    def state_dict(self) -> OrderedDict:
        return OrderedDict(frames=self._frames)

    def load_state_dict(self, state_dict: OrderedDict) -> None:
        self._frames = int(state_dict.get("frames", 0))

    def shutdown(self, timeout: float | None = None, close_env: bool = True, raise_on_error: bool = True) -> None:
        if close_env and not self._closed:
            for env in self.envs:
                env.close()
            self._closed = True

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(game={self.envs[0].game!r}, num_envs={self.num_envs}, "
            f"env_groups={len(self.envs)}, n_steps={self.n_steps}, device={self.device})"
        )
