"""The fast path: many Taxi agents (seeds, noise levels) trained in lockstep.

:func:`train_gym` runs one agent through TorchRL's collector and trainer, at
about 2,000 frames/s on one CPU core, dominated by per-step Python work in the
env, collector and trainer. For sweeps this module trains K agents as one
batched computation: every parameter has a leading agent dimension, the K x 16
environments are stepped with two table lookups (:class:`TabularModel`), and one
backward pass serves all agents. The algorithm is the same as the TorchRL
pipeline's, term by term (``tests/test_batched.py`` checks the losses against
TorchRL's ``A2CLoss`` and our loss modules on identical parameters, and the
learning curves against the TorchRL path):

* A2C with the TD(1) return of each 2-step rollout, bootstrapped from the critic
  (also at a time-limit truncation, not at a termination), L2 critic loss and
  entropy bonus;
* the dual or MLP inverse model's loss on the agent's own transitions;
* BC on the demo pair at each visited state (``rho=visited``) or on uniformly
  drawn pairs, labelled by the inverse model (or the true action for ``il``);
* one RMSprop step per rollout after clipping each agent's global gradient norm.

The one-hot embedding tables (500x500 per actor and critic) get a row-sparse
gradient; :class:`LazyRMSprop` updates only the touched rows and applies the
skipped rows' decay of the squared-gradient average when they are next touched,
which is exactly what dense RMSprop does to rows whose gradient is zero.

What a seed fixes: an agent's initial parameters and its demonstrations (the same
as :func:`train_gym` with that seed). Action sampling and env resets draw from a
generator shared by the batch, so a seed's run here is not bit-identical to its
TorchRL run, only statistically equivalent.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

from torchrl_hybrid.data.expert import EXPERT_ACTION_KEY
from torchrl_hybrid.experts import expected_return
from torchrl_hybrid.families.gym import GymConfig, make_taxi_demos, tabular_model
from torchrl_hybrid.modules import dual_product
from torchrl_hybrid.variants import get_variant

__all__ = ["LazyRMSprop", "BatchedTabularAgents", "train_taxi_batched", "structure_key"]

# config entries that may differ between the agents of one batch
PER_AGENT = ("seed", "out_dir", "demo.eta", "demo.epsilon", "demo.path", "demo.save_path")


def structure_key(cfg: GymConfig) -> str:
    """Configs with equal keys can be trained in one batch."""
    d = dataclasses.asdict(cfg)
    for path in PER_AGENT:
        *head, last = path.split(".")
        node = d
        for h in head:
            node = node[h]
        node.pop(last)
    return json.dumps(d, sort_keys=True)


class LazyRMSprop:
    """RMSprop (torch's defaults: no momentum, not centred) with per-agent global
    gradient-norm clipping, for dense ``[K, ...]`` parameters and row-sparse
    embedding tables ``[K * rows, D]`` whose gradients are sparse COO tensors.
    """

    def __init__(
        self,
        dense: Sequence[torch.Tensor],
        sparse: Sequence[tuple[torch.Tensor, int]],
        K: int,
        lr: float,
        alpha: float,
        eps: float,
        max_norm: float | None,
    ):
        self.dense, self.sparse, self.K = list(dense), list(sparse), K
        self.lr, self.alpha, self.eps, self.max_norm = lr, alpha, eps, max_norm
        self.v_dense = [torch.zeros_like(p) for p in self.dense]
        self.v_sparse = [torch.zeros_like(t) for t, _ in self.sparse]
        self.last = [torch.zeros(t.shape[0], dtype=torch.long) for t, _ in self.sparse]
        self.t = 0

    @torch.no_grad()
    def step(self) -> torch.Tensor:
        """Clips, updates, zeroes the gradients; returns the per-agent grad norms."""
        self.t += 1
        K = self.K
        norms2 = torch.zeros(K)
        grads = []
        for p in self.dense:
            g = p.grad if p.grad is not None else torch.zeros_like(p)
            norms2 += g.reshape(K, -1).pow(2).sum(1)
            grads.append(g)
        sgrads = []
        for table, rows in self.sparse:
            if table.grad is None:
                sgrads.append(None)
                continue
            g = table.grad.coalesce()
            idx, vals = g.indices()[0], g.values()
            norms2.index_add_(0, idx // rows, vals.pow(2).sum(1))
            sgrads.append((idx, vals))
        norms = norms2.sqrt()
        scale = torch.ones(K) if self.max_norm is None else (self.max_norm / (norms + 1e-6)).clamp(max=1.0)
        a, lr, eps = self.alpha, self.lr, self.eps
        grads = [g * scale.view(K, *([1] * (g.dim() - 1))) for g in grads]
        torch._foreach_mul_(self.v_dense, a)
        torch._foreach_addcmul_(self.v_dense, grads, grads, value=1 - a)
        denom = torch._foreach_add(torch._foreach_sqrt(self.v_dense), eps)
        torch._foreach_addcdiv_(self.dense, grads, denom, value=-lr)
        for p in self.dense:
            p.grad = None
        for (table, rows), sg, v, last in zip(self.sparse, sgrads, self.v_sparse, self.last):
            if sg is None:
                continue
            idx, vals = sg  # coalesced: each row once
            vals = vals * scale.index_select(0, idx // rows).unsqueeze(-1)
            decay = torch.pow(a, (self.t - last.index_select(0, idx)).float()).unsqueeze(-1)
            v_rows = v.index_select(0, idx).mul_(decay).addcmul_(vals, vals, value=1 - a)
            v.index_copy_(0, idx, v_rows)
            table.index_add_(0, idx, vals.div_(v_rows.sqrt_().add_(eps)), alpha=-lr)
            last.index_fill_(0, idx, self.t)
            table.grad = None
        return norms

    def dense_state_of_sparse(self, i: int) -> torch.Tensor:
        """The squared-gradient average of sparse table ``i`` as dense RMSprop
        would hold it now (pending decays applied): for tests."""
        return self.v_sparse[i] * torch.pow(self.alpha, (self.t - self.last[i]).float()).unsqueeze(-1)


def _side_by_side(factors: torch.Tensor) -> torch.Tensor:
    """[R, i, j] -> [i, R * j]."""
    R, i, j = factors.shape
    return factors.permute(1, 0, 2).reshape(i, R * j)


def _uniform(shape, bound, gen):
    return (torch.rand(shape, generator=gen) * 2 - 1) * bound


class BatchedTabularAgents:
    """Parameters and forward functions of K tabular hybrid agents.

    Layout per agent (matching :func:`~torchrl_hybrid.modules.tabular_net`, the
    inverse models and their initialisations):
    actor ``logits(s) = E_a[s] @ W_a + b_a`` (``E_a`` = identity-initialised
    embedding, its row s is the embedding of state s; without it ``W_a`` is the
    table), critic likewise; the dual model's ``W_s`` table, ``W_ds``, action
    embedding, ``M``, ``N`` and action head; or the MLP's ``W_s`` and layers.
    """

    def __init__(self, cfg: GymConfig, seeds: Sequence[int], n_states: int, n_actions: int):
        self.cfg, self.K, self.S, self.A = cfg, len(seeds), n_states, n_actions
        self.variant = get_variant(cfg.variant)
        K, S, A = self.K, n_states, n_actions
        dense: dict[str, list[torch.Tensor]] = {}
        sparse: dict[str, list[torch.Tensor]] = {}

        def add(store, name, value):
            store.setdefault(name, []).append(value)

        for seed in seeds:
            g = torch.Generator().manual_seed(int(seed))
            for head, out in (("a", A), ("c", 1)):
                if cfg.identity_embedding:
                    add(sparse, f"E_{head}", torch.eye(S))
                    add(dense, f"W_{head}", _uniform((S, out), 1 / math.sqrt(S), g))
                else:
                    add(sparse, f"W_{head}", _uniform((S, out), 1 / math.sqrt(S), g))
                add(dense, f"b_{head}", _uniform((out,), 1 / math.sqrt(S), g))
            kind = self.variant.inverse_model
            ds, d = cfg.d_state, cfg.d
            if kind is not None:
                add(sparse, "W_s", torch.randn((S, ds), generator=g))
            if kind == "dual":
                R = cfg.rank
                add(dense, "W_ds", _uniform((ds, d), 1 / math.sqrt(ds), g))
                add(dense, "act_emb", torch.randn((A, d), generator=g))
                # M_r, N_r side by side: [i, R * d], block r is M_r (one bmm for all r)
                add(dense, "M", _side_by_side(torch.randn((R, ds, d), generator=g) / math.sqrt(ds)))
                add(dense, "N", _side_by_side(torch.randn((R, d, d), generator=g) / math.sqrt(d)))
                add(dense, "W_i", _uniform((d, A), 1 / math.sqrt(d), g))
                add(dense, "b_i", _uniform((A,), 1 / math.sqrt(d), g))
            elif kind == "mlp":
                width = 2 * ds
                for i in range(cfg.mlp_layers):
                    add(dense, f"L{i}", _uniform((width, d), 1 / math.sqrt(width), g))
                    add(dense, f"c{i}", _uniform((d,), 1 / math.sqrt(width), g))
                    width = d
                add(dense, "W_i", _uniform((d, A), 1 / math.sqrt(d), g))
                add(dense, "b_i", _uniform((A,), 1 / math.sqrt(d), g))
        self.p = {k: torch.stack(v).requires_grad_() for k, v in dense.items()}
        self.t = {k: torch.cat(v).requires_grad_() for k, v in sparse.items()}  # [K * S, D]
        self.offset = (torch.arange(K) * S).unsqueeze(-1)

    # --- forward pieces; s, a: [K, n] integer tensors --------------------------------
    def rows(self, name: str, s: torch.Tensor) -> torch.Tensor:
        K, n = s.shape
        return F.embedding((s + self.offset).reshape(-1), self.t[name], sparse=True).view(K, n, -1)

    def _head(self, head: str, s: torch.Tensor) -> torch.Tensor:
        if self.cfg.identity_embedding:
            out = torch.bmm(self.rows(f"E_{head}", s), self.p[f"W_{head}"])
        else:
            out = self.rows(f"W_{head}", s)
        return out + self.p[f"b_{head}"].unsqueeze(1)

    def logits(self, s):
        return self._head("a", s)

    def value(self, s):
        return self._head("c", s).squeeze(-1)

    def _project(self, h, name):
        """h [K, n, i] times every factor r of [K, i, R * d] -> [K, n, R, d]."""
        return torch.bmm(h, self.p[name]).view(self.K, h.shape[1], self.cfg.rank, -1)

    def dual(self, h_s, h_x, hsM=None):
        """F(s, x) = sum_r (h_s M_r) * (h_x N_r) (:func:`~torchrl_hybrid.modules.dual_product`,
        as DualInverseDynamics); pass ``hsM`` to reuse h_s M_r."""
        if hsM is None:
            hsM = self._project(h_s, "M")
        return dual_product(hsM, self._project(h_x, "N"))

    def idm_terms(self, s, s2, a=None) -> dict[str, torch.Tensor]:
        h_s, h_s2 = self.rows("W_s", s), self.rows("W_s", s2)
        p = self.p
        if self.variant.inverse_model == "mlp":
            h = torch.cat([h_s, h_s2], -1)
            for i in range(self.cfg.mlp_layers):
                h = torch.relu(torch.bmm(h, p[f"L{i}"]) + p[f"c{i}"].unsqueeze(1))
            return {"action_logits": torch.bmm(h, p["W_i"]) + p["b_i"].unsqueeze(1)}
        h_ds = torch.bmm(h_s2 - h_s, p["W_ds"])
        hsM = self._project(h_s, "M")
        h_a_hat = self.dual(h_s, h_ds, hsM)
        out = {"action_logits": torch.bmm(h_a_hat, p["W_i"]) + p["b_i"].unsqueeze(1)}
        if a is not None:
            h_a = p["act_emb"][torch.arange(self.K).unsqueeze(-1), a]
            out.update(h_a=h_a, h_a_hat=h_a_hat, h_ds=h_ds, h_ds_hat=self.dual(h_s, h_a, hsM))
        return out

    @torch.no_grad()
    def infer(self, s, s2):
        return self.idm_terms(s, s2)["action_logits"].argmax(-1)

    def optimizer(self) -> LazyRMSprop:
        o = self.cfg.optim
        return LazyRMSprop(
            list(self.p.values()),
            [(t, self.S) for t in self.t.values()],
            self.K,
            lr=o.lr,
            alpha=o.alpha,
            eps=o.eps,
            max_norm=o.max_grad_norm,
        )


def a2c_terms(agents: BatchedTabularAgents, s, a, r, s2, terminated, done, gamma, critic_coeff, entropy_coeff):
    """TorchRL's ``A2CLoss`` with a TD(1) estimator on rollouts ``[K, envs, T]``."""
    K, E, T = s.shape
    flat = lambda x: x.reshape(K, E * T)  # noqa: E731
    logits = agents.logits(flat(s)).view(K, E, T, -1)
    logp_all = logits.log_softmax(-1)
    v = agents.value(flat(s)).view(K, E, T)
    with torch.no_grad():
        v_next = agents.value(flat(s2)).view(K, E, T)
        G = torch.zeros_like(v_next)
        nxt = v_next[..., -1]
        for t in reversed(range(T)):
            # inside the rollout a done step bootstraps from its own next state
            boot = torch.where(done[..., t], v_next[..., t], nxt) if t < T - 1 else v_next[..., t]
            G[..., t] = r[..., t] + gamma * (~terminated[..., t]) * boot
            nxt = G[..., t]
        adv = G - v.detach()
    logp = logp_all.gather(-1, a.unsqueeze(-1)).squeeze(-1)
    entropy = -(logp_all.exp() * logp_all).sum(-1)
    return {
        "loss_objective": -(logp * adv).mean((1, 2)),
        "loss_critic": critic_coeff * (v - G).pow(2).mean((1, 2)),
        "loss_entropy": -entropy_coeff * entropy.mean((1, 2)),
        "entropy": entropy.detach().mean((1, 2)),
    }


def idm_loss_terms(agents: BatchedTabularAgents, s, a, s2, lc) -> dict[str, torch.Tensor]:
    """The inverse-dynamics loss (dual: with the L1 embedding terms) per agent."""
    dual = agents.variant.inverse_model == "dual"
    t = agents.idm_terms(s, s2, a if dual else None)
    logp = t["action_logits"].log_softmax(-1)
    out = {
        "loss_inverse": -lc.idm_action_coeff * logp.gather(-1, a.unsqueeze(-1)).squeeze(-1).mean(1),
        "idm_accuracy": (t["action_logits"].argmax(-1) == a).float().mean(1).detach(),
    }
    if dual:
        out["loss_action_embedding"] = lc.idm_embedding_coeff * (t["h_a_hat"] - t["h_a"]).abs().mean((1, 2))
        out["loss_state_embedding"] = lc.idm_embedding_coeff * (t["h_ds_hat"] - t["h_ds"]).abs().mean((1, 2))
    return out


# label options of ExpertBCLoss beyond the paper, which bc_loss_terms does not implement
_BEYOND_THE_PAPER = (
    "bc_labels",
    "bc_confidence",
    "bc_entropy_floor",
    "bc_ready_accuracy",
    "bc_anneal_frames",
    "bc_updates",
    "idm_updates",
    "bc_prior_floor",
    "explore_envs",
)


def bc_loss_terms(agents: BatchedTabularAgents, es, es2, mask, bc_coeff: float, true_labels=None):
    """``ExpertBCLoss`` (argmax labels) per agent: ``-bc_coeff * mean log pi(M(s, s') | s)``
    over the expert pairs ``(es, es2)`` ``[K, B]`` where ``mask`` is set (the pairs at the
    visited states, or all of a uniform sample); ``true_labels`` for the IL baseline."""
    label = true_labels if true_labels is not None else agents.infer(es, es2)
    lp = agents.logits(es).log_softmax(-1).gather(-1, label.clamp(min=0).unsqueeze(-1)).squeeze(-1)
    count = mask.sum(1)
    mean_lp = (lp * mask).sum(1) / count.clamp(min=1)
    return {"loss_bc": -bc_coeff * mean_lp, "bc_batch_size": count.float()}


class _Demos:
    """Per-agent demo pairs, padded to [K, N]."""

    def __init__(self, demo_list, S):
        K = len(demo_list)
        n = torch.tensor([d.batch_size.numel() for d in demo_list])
        N = int(n.max())
        self.n = n
        self.obs = torch.zeros(K, N, dtype=torch.long)
        self.next = torch.zeros(K, N, dtype=torch.long)
        self.act = torch.full((K, N), -1, dtype=torch.long)
        self.valid = torch.arange(N).unsqueeze(0) < n.unsqueeze(1)
        for k, d in enumerate(demo_list):
            m = int(n[k])
            self.obs[k, :m], self.next[k, :m] = d["observation"], d["next", "observation"]
            if EXPERT_ACTION_KEY in d.keys():
                self.act[k, :m] = d[EXPERT_ACTION_KEY]
        # per-state lookup for rho=visited (at most one pair per state)
        self.has = torch.zeros(K, S, dtype=torch.bool)
        self.at = torch.zeros(K, S, dtype=torch.long)
        self.unique_states = True
        for k in range(K):
            m = int(n[k])
            s = self.obs[k, :m]
            if len(torch.unique(s)) != m:
                self.unique_states = False
            self.has[k, s] = True
            self.at[k, s] = torch.arange(m)


def train_taxi_batched(
    configs: Sequence[GymConfig],
    *,
    write_outputs: bool = True,
    plot: bool = True,
    progress: Callable[[int], None] | None = None,
) -> list[dict[str, Any]]:
    """Trains one agent per config, all in one batched computation.

    The configs must share everything but ``seed``, ``out_dir``, ``demo.eta``,
    ``demo.epsilon`` and ``demo.path`` (see :func:`structure_key`). Each agent
    gets the same outputs as :func:`train_gym` (``metrics.csv``,
    ``summary.json``, optionally ``learning_curve.png``); the summaries are returned.

    Args:
        configs: one per agent.
        write_outputs: write each agent's files into its ``out_dir``.
        plot: also draw each agent's PNG.
        progress: called with the frames of one agent after every update.
    """
    if not configs:
        raise ValueError("no configs given")
    cfg = configs[0].validate()
    keys = {structure_key(c.validate()) for c in configs}
    if len(keys) != 1:
        raise ValueError("configs differ in more than seed/out_dir/demo noise/demo path; batch them separately")
    if cfg.env.backend == "gym":
        raise ValueError("the batched fast path steps the tabular model; env.backend='gym' needs train_gym")
    if cfg.demo.rho == "curriculum":
        raise ValueError(
            "the batched fast path supports demo.rho = visited | uniform; use train_gym for the curriculum"
        )
    if cfg.loss.idm_forward_coeff > 0:
        raise ValueError("the batched fast path has no forward head; use train_gym for loss.idm_forward_coeff > 0")
    paper = type(cfg.loss)()
    beyond = [
        f"loss.{k}={getattr(cfg.loss, k)!r}" for k in _BEYOND_THE_PAPER if getattr(cfg.loss, k) != getattr(paper, k)
    ]
    if cfg.optim.clip != "global":
        beyond.append(f"optim.clip={cfg.optim.clip!r}")
    if beyond:
        raise ValueError(
            f"the batched fast path implements the paper's BC term (argmax labels, constant weight) and "
            f"one global gradient clip; {', '.join(beyond)} need engine=torchrl"
        )
    o = cfg.optim
    extras = {k: getattr(o, k) for k in ("weight_decay", "momentum", "centered", "maximize") if getattr(o, k)}
    if extras:
        raise ValueError(
            f"the batched fast path implements plain RMSprop (lr, alpha, eps); "
            f"{', '.join(f'optim.{k}' for k in extras)} (optim {extras}) need engine=torchrl"
        )
    variant = get_variant(cfg.variant)
    model = tabular_model(cfg.env.env_id, cfg.env.kwargs)
    S, A, K, E, T = model.n_states, model.n_actions, len(configs), cfg.env.num_envs, cfg.loss.n_steps
    demo_list, expert = [], None
    for c in configs:
        d, expert = make_taxi_demos(c, model, torch.Generator().manual_seed(c.seed))
        demo_list.append(d)
    demos = _Demos(demo_list, S)
    if variant.bc is not None and cfg.demo.rho == "visited" and not demos.unique_states:
        raise ValueError(
            "rho=visited in the batched fast path needs at most one demo pair per state "
            "(demo.form=per_state); use train_gym for other demo sets"
        )
    agents = BatchedTabularAgents(cfg, [c.seed for c in configs], S, A)
    opt = agents.optimizer()
    gen = torch.Generator().manual_seed(int(sum(c.seed * 1_000_003**i for i, c in enumerate(configs)) % 2**62))
    lc = cfg.loss
    kk = torch.arange(K).unsqueeze(-1)

    def reset_states(n):
        return torch.multinomial(model.initial_dist, K * n, replacement=True, generator=gen).view(K, n)

    def env_step(s, a):  # the same step as TabularEnv's
        return model.step(s, a, gen)

    @torch.no_grad()
    def evaluate(n_episodes: int) -> torch.Tensor:
        s = reset_states(n_episodes)
        ret = torch.zeros(K, n_episodes)
        alive = torch.ones(K, n_episodes, dtype=torch.bool)
        for _ in range(cfg.env.max_episode_steps):
            a = agents.logits(s).argmax(-1)
            s, r, term = env_step(s, a)
            ret += alive * r
            alive &= ~term
        return ret

    @torch.no_grad()
    def idm_accuracy() -> torch.Tensor:
        pred = agents.infer(demos.obs, demos.next)
        ok = (pred == demos.act) & demos.valid
        return ok.sum(1) / demos.valid.sum(1)

    s = reset_states(E)
    elapsed = torch.zeros(K, E, dtype=torch.long)
    ep_ret = torch.zeros(K, E)
    finished: list[list[float]] = [[] for _ in range(K)]
    rows: list[list[dict]] = [[] for _ in range(K)]
    frames, next_log = 0, 0
    per_batch = E * T
    t0 = time.perf_counter()
    last_losses: dict[str, torch.Tensor] = {}
    has_acc = variant.inverse_model is not None and bool((demos.act >= 0).any())

    def log_row():
        ev = evaluate(cfg.logger.eval_episodes).mean(1)
        acc = idm_accuracy() if has_acc else None
        for k in range(K):
            fin = finished[k]
            row = {"frames": frames, "return_mean": sum(fin) / len(fin) if fin else math.nan, "episodes": len(fin)}
            row.update({name: float(v[k]) for name, v in last_losses.items()})
            row["eval_return"] = float(ev[k])
            if acc is not None:
                row["idm_accuracy_expert"] = float(acc[k])
            row["time_s"] = round(time.perf_counter() - t0, 3)
            rows[k].append(row)
            finished[k] = []

    while frames < cfg.total_frames:
        # ---- collect T steps in K x E envs with the current policies ----
        buf = {n: [] for n in ("s", "a", "r", "s2", "term", "done")}
        with torch.no_grad():
            for _ in range(T):
                probs = agents.logits(s).softmax(-1)
                a = torch.multinomial(probs.view(-1, A), 1, generator=gen).view(K, E)
                s2, r, term = env_step(s, a)
                elapsed += 1
                trunc = (elapsed >= cfg.env.max_episode_steps) & ~term
                done = term | trunc
                ep_ret += r
                for n, x in zip(buf, (s, a, r, s2, term, done)):
                    buf[n].append(x)
                if done.any():
                    for k, e in done.nonzero().tolist():
                        finished[k].append(float(ep_ret[k, e]))
                    ep_ret[done] = 0
                    elapsed[done] = 0
                    s = torch.where(done, reset_states(E), s2)
                else:
                    s = s2
        b = {n: torch.stack(x, -1) for n, x in buf.items()}  # [K, E, T]
        frames += per_batch

        # ---- losses (summed over agents: each agent's gradient is its own) ----
        terms: dict[str, torch.Tensor] = {}
        if variant.rl:
            terms.update(
                a2c_terms(
                    agents,
                    b["s"],
                    b["a"],
                    b["r"],
                    b["s2"],
                    b["term"],
                    b["done"],
                    lc.gamma,
                    lc.critic_coeff,
                    lc.entropy_coeff,
                )
            )
        elif lc.entropy_coeff:
            lp = agents.logits(b["s"].reshape(K, -1)).log_softmax(-1)
            ent = -(lp.exp() * lp).sum(-1).mean(1)
            terms.update(loss_entropy=-lc.entropy_coeff * ent, entropy=ent.detach())
        flat_s, flat_a, flat_s2 = (b[n].reshape(K, -1) for n in ("s", "a", "s2"))
        if variant.inverse_model is not None:
            terms.update(idm_loss_terms(agents, flat_s, flat_a, flat_s2, lc))
        if variant.bc is not None:
            # as DelayedCoefficientHook: on once the frames before this batch reach the start
            bc_on = frames - per_batch >= lc.bc_start_frames
            if cfg.demo.rho == "visited":
                mask = demos.has[kk, flat_s]
                idx = demos.at[kk, flat_s]
            else:
                idx = (torch.rand(K, cfg.demo.batch_size, generator=gen) * demos.n.unsqueeze(1)).long()
                mask = torch.ones_like(idx, dtype=torch.bool)
            es, es2 = demos.obs[kk, idx], demos.next[kk, idx]
            terms.update(
                bc_loss_terms(
                    agents,
                    es,
                    es2,
                    mask,
                    lc.bc_coeff if bc_on else 0.0,
                    demos.act[kk, idx] if variant.bc == "true" else None,
                )
            )
        total = sum(v.sum() for n, v in terms.items() if n.startswith("loss_"))
        total.backward()
        terms["grad_norm"] = opt.step()
        last_losses = {n: v.detach() for n, v in terms.items()}
        if progress is not None:
            progress(per_batch)
        if frames >= next_log or frames >= cfg.total_frames:
            next_log = frames + cfg.logger.log_every_frames
            log_row()

    train_time = time.perf_counter() - t0
    final = evaluate(cfg.logger.final_eval_episodes)
    acc = idm_accuracy() if has_acc else None
    optimal = expected_return(model, expert, cfg.env.max_episode_steps)
    summaries = []
    for k, c in enumerate(configs):
        summary = {
            "variant": c.variant,
            "seed": c.seed,
            "frames": frames,
            "final_return": float(final[k].mean()),
            "final_return_std": float(final[k].std()),
            "final_eval_episodes": int(final.shape[1]),
            "optimal_return": optimal,
            "idm_accuracy_expert": None if acc is None else float(acc[k]),
            "train_time_s": round(train_time, 2),
            "frames_per_s": round(frames * K / train_time, 1),
            "batched_agents": K,
            "config": dataclasses.asdict(c),
            "curve": rows[k],
        }
        summaries.append(summary)
        if write_outputs:
            _write_outputs(c, summary, rows[k], plot)
    return summaries


def _write_outputs(cfg: GymConfig, summary: dict, rows: list[dict], plot: bool) -> None:
    out = Path(cfg.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with (out / "metrics.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)
    (out / "summary.json").write_text(json.dumps({k: v for k, v in summary.items() if k != "curve"}, indent=2))
    if plot:
        from torchrl_hybrid.utils.plotting import plot_learning_curve

        plot_learning_curve(
            rows,
            out / "learning_curve.png",
            title=f"Taxi, {cfg.variant}, seed {cfg.seed}",
            optimal=summary["optimal_return"],
        )
