"""Expert state-pair datasets: building, validating, saving, loading, buffering.

A dataset is a flat TensorDict of expert pairs with the entries

* ``"observation"``: the expert state s;
* ``("next", "observation")``: the state s' that followed it;
* ``"step"``: index of s within its trajectory (what the curriculum reads);
* ``"trajectory"``: id of the trajectory the pair comes from;
* ``EXPERT_ACTION_KEY`` (``"expert_action"``, optional): the action the expert
  really took. It is there only for the IL baseline and for measuring how well
  actions are inferred; :func:`make_expert_buffer` leaves it out unless asked, so
  the hybrid and BC learners cannot read it.

Pairs never span two trajectories.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Sequence
from pathlib import Path

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.data.replay_buffers.samplers import RandomSampler, Sampler

from torchrl_hybrid.envs.tabular import TabularModel
from torchrl_hybrid.utils.files import check_memmap_folder, read_json

__all__ = [
    "EXPERT_ACTION_KEY",
    "pairs_from_trajectories",
    "tabular_state_pairs",
    "tabular_trajectories",
    "validate_demos",
    "save_demos",
    "load_demos",
    "make_expert_buffer",
]

EXPERT_ACTION_KEY = "expert_action"


def pairs_from_trajectories(
    states: Sequence[torch.Tensor], actions: Sequence[torch.Tensor] | None = None
) -> TensorDict:
    """Expert pairs from state sequences (the paper's trajectory form).

    Args:
        states: one tensor per trajectory, ``[T_i + 1, *obs_shape]``: the visited
            states in order. Consecutive states within a trajectory become pairs;
            the last state of one trajectory is never paired with the first of the next.
        actions: optional true actions ``[T_i]`` per trajectory, stored under
            ``EXPERT_ACTION_KEY`` for diagnostics only.
    """
    if len(states) == 0:
        raise ValueError("no trajectories given")
    if actions is not None and len(actions) != len(states):
        raise ValueError(f"{len(actions)} action sequences for {len(states)} trajectories")
    parts = []
    for i, seq in enumerate(states):
        T = seq.shape[0] - 1
        if T < 1:
            continue
        td = TensorDict(
            {
                "observation": seq[:-1],
                ("next", "observation"): seq[1:],
                "step": torch.arange(T),
                "trajectory": torch.full((T,), i),
            },
            [T],
        )
        if actions is not None:
            if actions[i].shape[0] != T:
                raise ValueError(f"trajectory {i}: {T + 1} states need {T} actions, got {actions[i].shape[0]}")
            td[EXPERT_ACTION_KEY] = actions[i].long()
        parts.append(td)
    if not parts:
        raise ValueError("every trajectory has fewer than two states: no pairs")
    return torch.cat(parts)


def _successor(model: TabularModel, s: torch.Tensor, a: torch.Tensor, generator=None) -> torch.Tensor:
    if model.deterministic:
        return model.next_state[s, a, 0]
    k = torch.multinomial(model.prob[s, a], 1, generator=generator).squeeze(-1)
    return model.next_state[s, a, k]


def tabular_state_pairs(
    model: TabularModel, policy: torch.Tensor, states: torch.Tensor | None = None, generator=None
) -> TensorDict:
    """One expert pair ``(s, s')`` per state (the authors' Taxi demo form).

    Args:
        model: the MDP tables.
        policy: ``[S]`` the expert's action in each state.
        states: which states to cover; all by default.
    """
    s = torch.arange(model.n_states) if states is None else states.long()
    a = policy[s]
    n = len(s)
    return TensorDict(
        {
            "observation": s,
            ("next", "observation"): _successor(model, s, a, generator),
            "step": torch.zeros(n, dtype=torch.long),
            "trajectory": torch.arange(n),
            EXPERT_ACTION_KEY: a,
        },
        [n],
    )


def tabular_trajectories(
    model: TabularModel, policy: torch.Tensor, num_trajectories: int, max_steps: int = 200, generator=None
) -> TensorDict:
    """Pairs from ``num_trajectories`` expert episodes started from the start
    distribution (the paper's trajectory form), ``step`` counting from 0."""
    starts = torch.multinomial(model.initial_dist, num_trajectories, replacement=True, generator=generator)
    seqs, acts = [], []
    for s0 in starts.tolist():
        s, states, actions = torch.tensor(s0), [s0], []
        for _ in range(max_steps):
            a = policy[s]
            k = 0 if model.deterministic else int(torch.multinomial(model.prob[s, a], 1, generator=generator))
            done = bool(model.terminated[s, a, k])
            s = model.next_state[s, a, k]
            states.append(int(s))
            actions.append(int(a))
            if done:
                break
        seqs.append(torch.tensor(states))
        acts.append(torch.tensor(actions))
    return pairs_from_trajectories(seqs, acts)


def validate_demos(
    demos: TensorDictBase,
    *,
    obs_shape: Sequence[int] | None = None,
    obs_dtype: torch.dtype | None = None,
    source: str = "demos",
) -> TensorDictBase:
    """Checks a demo dataset and raises ``ValueError`` naming the problem and the fix."""
    for key in ("observation", ("next", "observation")):
        if key not in demos.keys(include_nested=True):
            raise ValueError(
                f"{source}: missing entry {key!r}; a demo dataset needs observation and ('next', 'observation')."
            )
    if demos.batch_size.numel() == 0:
        raise ValueError(f"{source}: the dataset is empty (0 pairs); regenerate it or point to another file.")
    for key in ("observation", ("next", "observation")):
        x = demos.get(key)
        if obs_shape is not None and tuple(x.shape[demos.ndim :]) != tuple(obs_shape):
            raise ValueError(
                f"{source}: {key!r} has observation shape {tuple(x.shape[demos.ndim :])}, but the env "
                f"produces {tuple(obs_shape)}; the demos were recorded for another env or preprocessing."
            )
        if x.dtype.is_floating_point and not torch.isfinite(x).all():
            raise ValueError(f"{source}: {key!r} holds NaN or infinite values; the dataset is corrupt, regenerate it.")
        if obs_dtype is not None and x.dtype.is_floating_point != obs_dtype.is_floating_point:
            raise ValueError(
                f"{source}: {key!r} has dtype {x.dtype}, the env produces {obs_dtype}; the demos were recorded for another env."
            )
    if "step" not in demos.keys():
        demos = demos.clone(False)
        demos["step"] = torch.zeros(demos.shape, dtype=torch.long)
    return demos


def save_demos(
    demos: TensorDictBase, path: str | Path, metadata: dict | None = None, *, overwrite: bool = False
) -> Path:
    """Writes the dataset as a memory-mapped TensorDict folder plus ``metadata.json``.
    A folder that already holds files is refused unless ``overwrite`` (then the
    folder is replaced whole)."""
    path = Path(path)
    if path.exists() and (not path.is_dir() or any(path.iterdir())):
        if not overwrite:
            raise ValueError(
                f"{path} already exists and is not empty; pass overwrite=true to replace it or choose another folder"
            )
        shutil.rmtree(path) if path.is_dir() else path.unlink()
    demos.memmap(path)
    (path / "metadata.json").write_text(json.dumps(metadata or {}, indent=2))
    return path


def load_demos(
    path: str | Path,
    *,
    obs_shape: Sequence[int] | None = None,
    obs_dtype: torch.dtype | None = None,
    require_metadata: str | None = None,
) -> tuple[TensorDictBase, dict]:
    """Loads a dataset written by :func:`save_demos` and validates it. A missing
    ``metadata.json`` reads as ``{}``, or, with ``require_metadata`` (how to record demos
    that have it), is refused with ``FileNotFoundError``."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"demo dataset {str(path)!r} does not exist; generate it first or fix the path.")
    if not path.is_dir():
        raise ValueError(f"{str(path)!r} is a file, not a demo dataset folder written by save_demos")
    check_memmap_folder(path)  # a truncated file would be padded with zeros (and extended on disk)
    try:
        demos = TensorDict.load_memmap(path)
    except Exception as err:  # a folder that is not a saved TensorDict
        raise ValueError(f"{str(path)!r} is not a demo dataset written by save_demos: {err}") from err
    meta_file = path / "metadata.json"
    if require_metadata is not None and not meta_file.exists():
        raise FileNotFoundError(
            f"{path}: no metadata.json (looked for {meta_file}), which says what the demos were "
            f"recorded on; these are not demos written by the recording recipe: {require_metadata}"
        )
    metadata = read_json(meta_file, "demo metadata") if meta_file.exists() else {}
    return validate_demos(demos, obs_shape=obs_shape, obs_dtype=obs_dtype, source=str(path)), metadata


def make_expert_buffer(
    demos: TensorDictBase,
    *,
    sampler: Sampler | None = None,
    batch_size: int | None = None,
    include_expert_actions: bool = False,
    device: str | torch.device | None = None,
) -> ReplayBuffer:
    """A TorchRL replay buffer holding the expert pairs.

    Args:
        demos: the dataset.
        sampler: how to draw pairs (``rho`` in the paper): uniform by default, a
            :class:`~torchrl_hybrid.data.CurriculumSampler` or a
            :class:`~torchrl_hybrid.data.VisitedStateSampler`.
        batch_size: default number of pairs per ``sample()``.
        include_expert_actions: keep ``EXPERT_ACTION_KEY`` in the buffer. Only the
            IL baseline needs it; state-only learners must not get it.
    """
    demos = validate_demos(demos)
    if not include_expert_actions:
        demos = demos.exclude(EXPERT_ACTION_KEY)
    elif EXPERT_ACTION_KEY not in demos.keys():
        raise ValueError(f"include_expert_actions=True but the demos have no {EXPERT_ACTION_KEY!r} entry")
    rb = ReplayBuffer(
        storage=LazyTensorStorage(demos.batch_size.numel(), device="cpu" if device is None else device),
        sampler=sampler if sampler is not None else RandomSampler(),
        batch_size=batch_size,
    )
    rb.extend(demos.reshape(-1))
    return rb
