"""Optimal experts for tabular MDPs, computed from the env's own transition table."""

from __future__ import annotations

import torch

from torchrl_hybrid.envs.tabular import TabularModel

__all__ = ["value_iteration", "optimal_policy", "expected_return", "episode_ends"]


def value_iteration(
    model: TabularModel, gamma: float = 1.0, tol: float = 1e-9, max_iters: int = 10_000
) -> tuple[torch.Tensor, torch.Tensor]:
    """State values ``V[S]`` and action values ``Q[S, A]`` of the optimal policy.

    With ``gamma=1`` (the default) this is the undiscounted optimum, i.e. the
    shortest-path solution for episodic tasks such as Taxi. Values are in float64.
    """
    p, r = model.prob.double(), model.reward.double()
    cont = (~model.terminated).double()
    V = torch.zeros(model.n_states, dtype=torch.float64)
    for _ in range(max_iters):
        Q = (p * (r + gamma * cont * V[model.next_state])).sum(-1)
        V_new = Q.max(-1).values
        if (V_new - V).abs().max() < tol:
            return V_new, Q
        V = V_new
    raise RuntimeError(f"value iteration did not converge in {max_iters} iterations")


def optimal_policy(model: TabularModel, gamma: float = 0.99) -> tuple[torch.Tensor, torch.Tensor]:
    """The deterministic optimal policy ``pi[S]`` (lowest index among ties) and the
    boolean mask ``optimal[S, A]`` of every action that is optimal in each state.

    ``gamma < 1`` (the default, 0.99) makes the expert prefer the shortest way to a
    reward: with ``gamma = 1`` and a reward only at the goal (FrozenLake), every
    action that keeps the goal reachable ties, walking into a wall among them, and the
    lowest-index tie (LEFT) loops forever. On Taxi (-1 a step) both give the same
    shortest-path expert (mean return 7.93)."""
    _, Q = value_iteration(model, gamma)
    best = Q.max(-1, keepdim=True).values
    optimal = Q >= best - 1e-6
    return optimal.float().argmax(-1), optimal


def episode_ends(model: TabularModel, policy: torch.Tensor, horizon: int) -> torch.Tensor:
    """``[n_starts]`` bool: whether a deterministic ``policy[S]`` reaches a terminal
    state within ``horizon`` steps from each possible start state (deterministic MDP)."""
    if not model.deterministic:
        raise ValueError("episode_ends needs a deterministic MDP")
    s = torch.nonzero(model.initial_dist > 0).squeeze(-1)
    ended = torch.zeros(len(s), dtype=torch.bool)
    for _ in range(horizon):
        a = policy[s]
        ended |= model.terminated[s, a, 0]
        s = model.next_state[s, a, 0]
    return ended


def expected_return(model: TabularModel, policy: torch.Tensor, horizon: int = 200) -> float:
    """Exact mean undiscounted return of a deterministic ``policy[S]`` from the start
    distribution, in a deterministic MDP, with episodes capped at ``horizon`` steps."""
    if not model.deterministic:
        raise ValueError("expected_return needs a deterministic MDP")
    starts = torch.nonzero(model.initial_dist > 0).squeeze(-1)
    s, ret = starts.clone(), torch.zeros(len(starts), dtype=torch.float64)
    alive = torch.ones(len(starts), dtype=torch.bool)
    for _ in range(horizon):
        a = policy[s]
        ret += alive * model.reward[s, a, 0].double()
        alive &= ~model.terminated[s, a, 0]
        s = model.next_state[s, a, 0]
    w = model.initial_dist[starts].double()
    return float((ret * w).sum() / w.sum())
