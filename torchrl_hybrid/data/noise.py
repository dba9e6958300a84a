"""Noisy demonstrations (the paper's robustness study).

* ``eta``: fraction of states missing from the demos;
* ``epsilon``: fraction of demo transitions produced by a non-optimal action
  instead of the expert's.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase

from torchrl_hybrid.data.expert import EXPERT_ACTION_KEY, _successor
from torchrl_hybrid.envs.tabular import TabularModel

__all__ = ["apply_demo_noise"]


def _check_ratio(name: str, value: float) -> None:
    if not 0.0 <= value < 1.0:
        raise ValueError(f"{name} must be in [0, 1), got {value}")


def apply_demo_noise(
    demos: TensorDictBase,
    model: TabularModel,
    optimal: torch.Tensor,
    *,
    eta: float = 0.0,
    epsilon: float = 0.0,
    epsilon_mode: str = "non_optimal",
    random_actions: tuple[int, ...] = (0, 1, 2, 3),
    generator: torch.Generator | None = None,
) -> TensorDictBase:
    """Returns a noisy copy of tabular demos.

    Exactly ``floor(eta * n)`` of the ``n`` distinct demo states are removed (with
    all their pairs); then exactly ``floor(epsilon * m)`` of the ``m`` remaining
    pairs are redrawn: the action becomes one chosen uniformly among the
    non-optimal actions of that state and ``s'`` its successor in ``model``.
    ``EXPERT_ACTION_KEY`` is updated to the action that produced each pair.

    Args:
        demos: pairs with integer ``observation`` and ``EXPERT_ACTION_KEY``.
        model: the MDP tables.
        optimal: ``[S, A]`` bool, the optimal actions (see ``optimal_policy``).
        eta: missing-state ratio in [0, 1).
        epsilon: non-optimal-action ratio in [0, 1).
        epsilon_mode: ``"non_optimal"`` (above: an exact fraction of pairs made by a
            non-optimal action) or ``"authors"``: as the authors' Taxi code, each
            pair is redrawn with probability ``epsilon`` with an action drawn
            uniformly from ``random_actions`` (Taxi's four moves), which may
            happen to be optimal.
        random_actions: the actions ``"authors"`` mode draws from.
        generator: torch random generator (seed it for reproducible noise).
    """
    _check_ratio("eta", eta)
    _check_ratio("epsilon", epsilon)
    demos = demos.clone()
    if eta > 0:
        states = torch.unique(demos["observation"])
        n_drop = int(eta * len(states))
        drop = states[torch.randperm(len(states), generator=generator)[:n_drop]]
        demos = demos[~torch.isin(demos["observation"], drop)]
    if epsilon_mode not in ("non_optimal", "authors"):
        raise ValueError(f"epsilon_mode must be 'non_optimal' or 'authors', got {epsilon_mode!r}")
    if epsilon > 0 and epsilon_mode == "authors":
        s = demos["observation"]
        rows = torch.nonzero(torch.rand(s.shape, generator=generator) < epsilon).squeeze(-1)
        choices = torch.tensor(random_actions)
        a = choices[torch.randint(len(choices), rows.shape, generator=generator)]
        demos[EXPERT_ACTION_KEY][rows] = a
        demos[("next", "observation")][rows] = _successor(model, s[rows], a, generator)
        demos.set("corrupted", torch.zeros(demos.shape, dtype=torch.bool))
        demos["corrupted"][rows] = True
    elif epsilon > 0:
        n_bad = int(epsilon * demos.batch_size.numel())
        s = demos["observation"]
        candidates = torch.nonzero((~optimal[s]).any(-1)).squeeze(-1)
        if len(candidates) < n_bad:
            raise ValueError(f"only {len(candidates)} demo states have a non-optimal action; cannot corrupt {n_bad}")
        rows = candidates[torch.randperm(len(candidates), generator=generator)[:n_bad]]
        bad = (~optimal[s[rows]]).float()
        a = torch.multinomial(bad, 1, generator=generator).squeeze(-1)
        demos[EXPERT_ACTION_KEY][rows] = a
        demos[("next", "observation")][rows] = _successor(model, s[rows], a, generator)
        demos.set("corrupted", torch.zeros(demos.shape, dtype=torch.bool))
        demos["corrupted"][rows] = True
    return demos
