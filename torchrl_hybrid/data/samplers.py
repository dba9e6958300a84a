"""Samplers that choose which expert pairs the BC term sees (rho in the paper)."""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.data.replay_buffers.samplers import Sampler
from torchrl.data.replay_buffers.storages import Storage

__all__ = ["CurriculumSampler", "VisitedStateSampler"]


def _storage_entry(storage: Storage, key) -> torch.Tensor:
    """Entry ``key`` of every stored item. A tensor storage (TorchRL's ``LazyTensorStorage``,
    ``LazyMemmapStorage``) gives a view of that one entry: reading the items whole would copy
    every field (with Atari demos, every frame stack) to learn one integer per pair."""
    n = len(storage)
    data = getattr(storage, "_storage", None)
    if isinstance(data, TensorDictBase):
        return data.get(key)[:n]
    return storage.get(torch.arange(n)).get(key)  # other storages (lists of items): no column to read


class CurriculumSampler(Sampler):
    """Samples uniformly among the pairs whose step index in their trajectory is
    below ``K``; ``K = k0 + frames // frames_per_step`` grows with training.

    This is the paper's Atari curriculum (``k0=10``, ``K += 1`` about every 8,000
    frames): early on the BC term only sees expert states near the start of a
    trajectory, which resemble the agent's own. A hook calls :meth:`update` with
    the number of frames collected so far.

    Args:
        k0: initial K (>= 1).
        frames_per_step: frames between two increments of K (> 0).
        step_key: entry holding the step index. Defaults to ``"step"``.

    Examples:
        >>> from torchrl.data import LazyTensorStorage, ReplayBuffer
        >>> from tensordict import TensorDict
        >>> sampler = CurriculumSampler(k0=2, frames_per_step=100)
        >>> rb = ReplayBuffer(storage=LazyTensorStorage(10), sampler=sampler)
        >>> _ = rb.extend(TensorDict({"step": torch.arange(10)}, [10]))
        >>> bool((rb.sample(64)["step"] < 2).all())
        True
        >>> sampler.update(frames=350); sampler.k
        5
    """

    def __init__(self, k0: int = 10, frames_per_step: int = 8000, step_key="step"):
        if k0 < 1:
            raise ValueError(f"k0 must be >= 1, got {k0}")
        if frames_per_step <= 0:
            raise ValueError(f"frames_per_step must be > 0, got {frames_per_step}")
        self.k0, self.frames_per_step, self.step_key = int(k0), int(frames_per_step), step_key
        self.frames = 0
        self._steps: torch.Tensor | None = None
        self._eligible: tuple[int, torch.Tensor] | None = None

    @property
    def k(self) -> int:
        return self.k0 + self.frames // self.frames_per_step

    def update(self, frames: int) -> None:
        """Sets the number of frames collected so far (K follows)."""
        self.frames = int(frames)

    def extend(self, index) -> None:
        self._steps = None

    def add(self, index) -> None:
        self._steps = None

    def sample(self, storage: Storage, batch_size: int) -> tuple[torch.Tensor, dict]:
        if len(storage) == 0:
            raise RuntimeError("CurriculumSampler: the expert buffer is empty")
        if self._steps is None or len(self._steps) != len(storage):
            self._steps, self._eligible = _storage_entry(storage, self.step_key).reshape(-1), None
        k = self.k
        if self._eligible is None or self._eligible[0] != k:  # K changes every few thousand frames
            self._eligible = (k, torch.nonzero(self._steps < k).squeeze(-1))
        eligible = self._eligible[1]
        if eligible.numel() == 0:
            raise RuntimeError(
                f"CurriculumSampler: no expert pair has {self.step_key!r} < K={self.k}; "
                "check that the demos carry step indices starting at 0."
            )
        pick = torch.randint(eligible.numel(), (batch_size,), generator=self._rng)
        return eligible[pick.to(eligible.device)], {"K": k}

    def _empty(self):
        self._steps = None

    def state_dict(self) -> dict[str, Any]:
        return {"k0": self.k0, "frames_per_step": self.frames_per_step, "frames": self.frames}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.k0 = int(state_dict["k0"])
        self.frames_per_step = int(state_dict["frames_per_step"])
        self.frames = int(state_dict["frames"])

    def dumps(self, path):
        torch.save(self.state_dict(), f"{path}/curriculum_sampler.pt")

    def loads(self, path):
        self.load_state_dict(torch.load(f"{path}/curriculum_sampler.pt"))

    def __repr__(self):
        return f"CurriculumSampler(k0={self.k0}, frames_per_step={self.frames_per_step}, K={self.k})"


class VisitedStateSampler(Sampler):
    """Picks expert pairs at the states the agent just visited (discrete states).

    After :meth:`observe` is given the agent's latest states, :meth:`sample`
    returns, for each visited state that has expert pairs, one of those pairs at
    random: the sample has one entry per such visit (so ``batch_size`` is ignored
    and the sample may be empty). This is how the authors' Taxi code applied the
    BC term, and it matches rho to the agent's own state distribution.

    Args:
        n_states: number of discrete states.
        state_key: entry holding the (integer) expert state. Defaults to ``"observation"``.
    """

    def __init__(self, n_states: int, state_key="observation"):
        self.n_states, self.state_key = int(n_states), state_key
        self._visited = torch.zeros(0, dtype=torch.long)
        self._index: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None

    def observe(self, states: torch.Tensor) -> None:
        """Records the agent's latest states (integer indices, any shape)."""
        if states.dtype.is_floating_point:
            raise ValueError("VisitedStateSampler needs integer state indices")
        self._visited = states.reshape(-1).long()

    def extend(self, index) -> None:
        self._index = None

    def add(self, index) -> None:
        self._index = None

    def _build(self, storage):
        s = _storage_entry(storage, self.state_key).reshape(-1).long()
        if s.numel() and (s.min() < 0 or s.max() >= self.n_states):
            raise ValueError(f"expert states outside [0, {self.n_states})")
        order = torch.argsort(s, stable=True)
        counts = torch.bincount(s, minlength=self.n_states)
        offsets = torch.cumsum(counts, 0) - counts
        self._index = (order, counts, offsets)

    def sample(self, storage: Storage, batch_size: int) -> tuple[torch.Tensor, dict]:
        if self._index is None:
            self._build(storage)
        assert self._index is not None  # set by _build
        order, counts, offsets = self._index
        v = self._visited.to(counts.device)
        inside = (v >= 0) & (v < self.n_states)
        v = v[inside & (counts[v.clamp(0, self.n_states - 1)] > 0)]  # one sync: the visits that have pairs
        r = (torch.rand(v.shape, generator=self._rng).to(v.device) * counts[v]).long()
        return order[offsets[v] + r], {}

    def _empty(self):
        self._index = None

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        return

    def dumps(self, path):
        return

    def loads(self, path):
        return
