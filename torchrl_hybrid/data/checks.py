"""Checks of loaded demos against what the env says about them.

:func:`~torchrl_hybrid.data.validate_demos` checks a dataset on its own (entries, shape,
dtype, finite values); the functions here check it against the env it is meant for, as
far as the env allows:

* :func:`check_trajectories`: within a trajectory, step t's next observation must be step
  t+1's observation (any env; demos in trajectory form: pairs with ``trajectory`` and
  ``step`` indices);
* :func:`check_observation_space`: vector observations must lie in the env's ``Box``;
* :func:`check_tabular_transitions`: every pair (s, s') must be a transition of the env's
  table ``P`` and, where the true actions are stored, (s, a, s') too.

Each raises ``ValueError`` with one line: the source, how many pairs fail out of how many,
the first failing pair, and how to get good demos.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDictBase

from torchrl_hybrid.envs.tabular import TabularModel

__all__ = [
    "BOUND_SLACK",
    "UNBOUNDED_LIMIT",
    "check_trajectories",
    "check_observation_space",
    "check_tabular_transitions",
]

#: the largest |x| accepted in an observation dimension the env leaves unbounded (CartPole's
#: velocities; gymnasium writes these bounds as inf or as float32's max). OURS: no physical
#: quantity of a classic-control env comes near it (CartPole's velocities stay within a few
#: units), while scaled or unnormalised recordings (e.g. x 1e6, raw pixels) go far beyond it.
UNBOUNDED_LIMIT = 1e4
#: how far past a finite bound an observation may lie, as a share of the bound's range: some envs
#: declare bounds that their physics leaves (LunarLander-v3's y position reaches about 5.9 with its
#: main engine held on, past the declared 2.5). OURS: a whole range beyond still refuses scaled
#: recordings (x 1e6) and those of another env.
BOUND_SLACK = 1.0
#: a bound at least this large stands for "no bound" (float32's max is 3.4e38)
_INFINITE_BOUND = 1e30


def check_trajectories(
    demos: TensorDictBase, source: str, fix: str, *, sample: int | None = None, seed: int = 0
) -> None:
    """Refuses demos whose pairs do not chain within a trajectory: the pair at step t and the
    pair at step t+1 of the same trajectory must share a state (s'_t == s_{t+1}; floats within
    1e-5). Skipped for pairs without ``trajectory`` (e.g. one pair per state), across gaps in
    ``step`` (states dropped by ``demo.eta``) and after pairs marked ``corrupted`` (redrawn by
    ``demo.epsilon``). ``sample``: check at most that many links, drawn with ``seed`` (large
    image datasets)."""
    if "trajectory" not in demos.keys() or "step" not in demos.keys():
        return
    n = demos.batch_size.numel()
    traj, step = demos["trajectory"].reshape(n).long(), demos["step"].reshape(n).long()
    order = torch.argsort(traj * (int(step.max()) + 2) + step, stable=True)
    a, b = order[:-1], order[1:]  # pair a is followed by pair b in (trajectory, step) order
    link = (traj[a] == traj[b]) & (step[b] == step[a] + 1)
    if "corrupted" in demos.keys():
        link &= ~demos["corrupted"].reshape(n).bool()[a]
    a, b = a[link], b[link]
    what = "consecutive pairs"
    if sample is not None and len(a) > sample:
        pick = torch.randperm(len(a), generator=torch.Generator().manual_seed(seed))[:sample].sort().values
        a, b, what = a[pick], b[pick], f"sampled {what}"
    if len(a) == 0:
        return
    obs, nxt = demos["observation"], demos["next", "observation"]
    obs, nxt = obs.reshape(n, *obs.shape[demos.ndim :]), nxt.reshape(n, *nxt.shape[demos.ndim :])
    x, y = nxt[a], obs[b]
    same = torch.isclose(x, y, rtol=1e-5, atol=1e-5) if x.dtype.is_floating_point else x == y
    bad = ~same.reshape(len(a), -1).all(-1)
    if bool(bad.any()):
        i = int(a[bad].min())
        raise ValueError(
            f"{source}: {int(bad.sum())} of {len(a)} {what} within a trajectory do not chain (the next observation "
            f"of step t must be the observation of step t+1; first: pair {i}, trajectory {int(traj[i])}, step "
            f"{int(step[i])}); the next states are shuffled or these are not recorded trajectories: {fix}"
        )


def check_observation_space(
    demos: TensorDictBase, low, high, source: str, fix: str, *, env_id: str = "the env"
) -> None:
    """Refuses vector observations outside the env's ``Box(low, high)``: a dimension with
    finite bounds accepts up to :data:`BOUND_SLACK` times its range beyond each bound (some envs
    leave their declared bounds); a dimension without a bound (inf, or float32's max) accepts
    |x| <= :data:`UNBOUNDED_LIMIT`."""
    low = torch.as_tensor(np.asarray(low, dtype=np.float64)).reshape(-1)
    high = torch.as_tensor(np.asarray(high, dtype=np.float64)).reshape(-1)
    unbounded_low = ~torch.isfinite(low) | (low <= -_INFINITE_BOUND)
    unbounded_high = ~torch.isfinite(high) | (high >= _INFINITE_BOUND)
    bounded = ~unbounded_low & ~unbounded_high
    slack = torch.where(bounded, BOUND_SLACK * (high - low), torch.zeros_like(low)) + 1e-5 * torch.maximum(
        low.abs(), high.abs()
    ).clamp(min=1).nan_to_num(posinf=1.0)
    lo = torch.where(unbounded_low, torch.full_like(low, -UNBOUNDED_LIMIT), low - slack)
    hi = torch.where(unbounded_high, torch.full_like(high, UNBOUNDED_LIMIT), high + slack)
    n = demos.batch_size.numel()
    first = None
    out = torch.zeros(n, dtype=torch.bool)
    for key in ("observation", ("next", "observation")):
        x = demos[key].reshape(n, -1).double()
        if x.shape[1] != len(lo):
            return  # another shape: validate_demos names that
        outside = (x < lo) | (x > hi)
        rows = outside.any(-1)
        if bool(rows.any()):
            i = int(rows.nonzero()[0])
            if first is None or i < first[0]:
                d = int(outside[i].nonzero()[0])
                first = (i, key, d, float(x[i, d]))
        out |= rows
    if first is not None:
        i, key, d, v = first
        raise ValueError(
            f"{source}: {int(out.sum())} of {n} pairs have observations outside the observation space of {env_id} "
            f"(first: pair {i}, {key!r}[{d}] = {v:.6g}, allowed [{float(lo[d]):.6g}, {float(hi[d]):.6g}]; "
            f"dimensions without a bound allow |x| <= {UNBOUNDED_LIMIT:g}); the demos are scaled, unnormalised or "
            f"recorded on another env: {fix}"
        )


def check_tabular_transitions(
    demos: TensorDictBase,
    model: TabularModel,
    source: str,
    fix: str,
    *,
    env_id: str = "the env",
    action_key: str = "expert_action",
) -> None:
    """Refuses tabular demos that the env's table ``P`` cannot have produced: states outside
    ``[0, n_states)``; pairs (s, s') that no action makes; and, where the true actions are
    stored under ``action_key``, triples (s, a, s') where ``a`` does not lead from s to s'."""
    s = torch.cat([demos["observation"].reshape(-1), demos["next", "observation"].reshape(-1)])
    if s.min() < 0 or s.max() >= model.n_states:
        raise ValueError(f"{source}: states outside [0, {model.n_states}); demos are for another env")
    # every pair must be a transition of the env under some action (the table says which)
    obs, nxt = demos["observation"].reshape(-1), demos["next", "observation"].reshape(-1)
    possible = ((model.next_state[obs] == nxt.view(-1, 1, 1)) & (model.prob[obs] > 0)).flatten(1).any(-1)
    if not bool(possible.all()):
        i = int((~possible).nonzero()[0])
        raise ValueError(
            f"{source}: {int((~possible).sum())} of {possible.numel()} pairs are not transitions "
            f"of {env_id} under any action (first: pair {i}, {int(obs[i])} -> {int(nxt[i])}); "
            f"demos for another env, or shuffled next states: {fix}"
        )
    if action_key not in demos.keys():
        return
    act = demos[action_key].reshape(-1).long()
    valid = (act >= 0) & (act < model.n_actions)
    a = act.clamp(0, model.n_actions - 1)
    leads = ((model.next_state[obs, a] == nxt.view(-1, 1)) & (model.prob[obs, a] > 0)).any(-1) & valid
    if not bool(leads.all()):
        i = int((~leads).nonzero()[0])
        raise ValueError(
            f"{source}: {int((~leads).sum())} of {leads.numel()} pairs (s, a, s') are not transitions "
            f"of {env_id}: the stored action {action_key!r} does not lead from s to s' (first: pair "
            f"{i}, {int(obs[i])} -a={int(act[i])}-> {int(nxt[i])}); the actions are not the ones that "
            f"made these demos: {fix}, or drop the {action_key!r} entry if the true actions are unknown "
            "(variant=il needs them)"
        )
