"""What labels the inverse model gives the expert's pairs, next to the expert's true actions
and the agent's own preferred actions at the same states (the feedback loop behind the
Atari results: where (s, s') shows no action, the labels follow the agent's habits).

    python benchmarks/atari_inverse_labels.py --model results/atari/compare_5m/Qbert/hybrid_dual_s0/model.pt \
        --demos demos/qbert --out results/atari/inverse_labels_qbert.json --plot results/atari/inverse_labels_qbert.png

``--model``: a ``model.pt`` of a hybrid run (``recipes/atari_compare.py`` / ``train_atari``;
it holds the actor and the inverse model). ``--demos``: the dataset that run learned from
(``recipes/atari_demos.py``; it keeps the true actions for diagnostics only). Prints, per
action, the share of the expert's true actions, of the inverse model's argmax labels and of
the agent's greedy actions at the expert's states, the labels' accuracy, how often the label
equals the agent's greedy action, the mean confidence (max P_i), what a confidence gate
(``loss.bc_confidence``) would keep at a few thresholds, and which true actions each label
stands for (the columns of the true x label confusion matrix: look-alike actions merged into one
label show up as one label taking several true actions). The figure draws the shares and the
confusion matrix.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from torchrl_hybrid.data import EXPERT_ACTION_KEY, load_demos
from torchrl_hybrid.envs.atari import action_names
from torchrl_hybrid.modules import AtariEncoder, make_atari_actor_critic
from torchrl_hybrid.trainers.run import make_inverse_model
from torchrl_hybrid.variants import get_variant

CONFIDENCE_THRESHOLDS = (0.5, 0.6, 0.8, 0.9)


def load_hybrid(path: str | Path):
    """The actor and the inverse model of a hybrid run's ``model.pt`` (sharing one CNN, or each
    with its own where the run had ``idm_encoder=own``: as trained)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"--model {path}: no such file (a model.pt written by train_atari)")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # truncated, another format
        raise ValueError(
            f"--model {path} is not a model.pt written by train_atari ({type(err).__name__}: {err})"
        ) from None
    if not isinstance(ckpt, dict) or ckpt.get("inverse_model") is None or "n_actions" not in ckpt:
        raise ValueError(f"{path}: not the model.pt of an Atari run with an inverse model (a2c has none)")
    cfg = ckpt["config"]
    actor, _, encoder, _ = make_atari_actor_critic(ckpt["n_actions"])
    idm_encoder = AtariEncoder() if cfg.get("idm_encoder", "shared") == "own" else encoder  # as trained
    idm = make_inverse_model(
        get_variant(cfg["variant"]).inverse_model,
        idm_encoder,
        ckpt["n_actions"],
        d_state=cfg["d_state"],
        d=cfg["d"],
        rank=cfg["rank"],
        mlp_layers=cfg.get("mlp_layers", 2),
    )
    actor.load_state_dict(ckpt["actor"])
    idm.load_state_dict(ckpt["inverse_model"])
    encoder.reuse_features = idm_encoder.reuse_features = False  # every call here is a new batch
    return actor.eval(), idm.eval(), ckpt


@torch.no_grad()
def inverse_labels(model: str | Path, demos: str | Path, batch: int = 256) -> dict:
    actor, idm, ckpt = load_hybrid(model)
    pairs, meta = load_demos(demos)
    if meta.get("game") not in (None, ckpt["config"]["env"]["game"]):
        raise ValueError(f"{demos} holds {meta['game']} demos, {model} plays {ckpt['config']['env']['game']}")
    if EXPERT_ACTION_KEY not in pairs.keys():
        raise ValueError(f"{demos} keeps no true actions ({EXPERT_ACTION_KEY}): the labels cannot be checked")
    n_actions = ckpt["n_actions"]
    labels, conf, greedy = [], [], []
    for i in range(0, len(pairs), batch):
        part = pairs[i : i + batch]
        probs = idm.action_logits(part["observation"], part["next", "observation"]).softmax(-1)
        c, lab = probs.max(-1)
        labels.append(lab)
        conf.append(c)
        greedy.append(actor(part.select("observation").clone())["logits"].argmax(-1))
    labels, conf, greedy = torch.cat(labels), torch.cat(conf), torch.cat(greedy)
    true = pairs[EXPERT_ACTION_KEY]

    def share(x):
        return (torch.bincount(x, minlength=n_actions).float() / len(x)).tolist()

    game = ckpt["config"]["env"]["game"]
    names = action_names(game)
    if len(names) != n_actions:
        raise ValueError(f"{model} has {n_actions} actions, {game}'s minimal action set {len(names)}")
    # confusion[t][l]: share of all pairs whose true action is t and whose label is l
    confusion = torch.bincount(true * n_actions + labels, minlength=n_actions**2).float() / len(true)
    return {
        "model": str(model),
        "demos": str(demos),
        "game": game,
        "variant": ckpt["config"]["variant"],
        "pairs": len(pairs),
        "actions": n_actions,
        "action_names": names,
        "confusion": confusion.view(n_actions, n_actions).tolist(),
        "share_true": share(true),
        "share_labels": share(labels),
        "share_agent_greedy": share(greedy),
        "accuracy": float((labels == true).float().mean()),
        "labels_equal_agent_greedy": float((labels == greedy).float().mean()),
        "agent_greedy_equals_expert": float((greedy == true).float().mean()),
        "mean_confidence": float(conf.mean()),
        "majority_true_share": max(share(true)),
        # what loss.bc_confidence=t would keep: the share of pairs with max P_i >= t and their labels' accuracy
        "confidence_gate": {
            str(t): {
                "kept": float((conf >= t).float().mean()),
                "accuracy": float((labels == true)[conf >= t].float().mean()) if (conf >= t).any() else None,
            }
            for t in CONFIDENCE_THRESHOLDS
        },
    }


def plot(r: dict, path: str | Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    n, names = r["actions"], r.get("action_names") or [str(a) for a in range(r["actions"])]
    x, w = np.arange(n), 0.27
    fig, (ax, cx) = plt.subplots(1, 2, figsize=(11, 3.8), gridspec_kw={"width_ratios": [1.5, 1]})
    ax.bar(x - w, r["share_true"], w, label="expert's true action")
    ax.bar(x, r["share_labels"], w, label=f"inverse model's label (accuracy {r['accuracy']:.1%})")
    ax.bar(x + w, r["share_agent_greedy"], w, label="agent's greedy action at s")
    ax.set_xticks(x, names, rotation=45, ha="right", fontsize=8)
    ax.set_ylabel("share of the expert's pairs")
    ax.set_title(
        f"{r['game']}, {r['variant']}: labels equal the agent's greedy action in "
        f"{r['labels_equal_agent_greedy']:.0%} of pairs",
        fontsize=9,
    )
    ax.legend(fontsize=8)
    if "confusion" in r:
        c = np.array(r["confusion"])
        rows = c / np.maximum(c.sum(1, keepdims=True), 1e-12)  # P(label | true action)
        im = cx.imshow(rows, vmin=0, vmax=1, cmap="viridis")
        cx.set_xticks(x, names, rotation=45, ha="right", fontsize=7)
        cx.set_yticks(x, names, fontsize=7)
        cx.set_xlabel("inverse model's label")
        cx.set_ylabel("expert's true action")
        cx.set_title("P(label | true action)", fontsize=9)
        fig.colorbar(im, ax=cx, fraction=0.046)
    else:
        cx.set_visible(False)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", required=True)
    p.add_argument("--demos", required=True)
    p.add_argument("--out", default=None, help="write the result as JSON")
    p.add_argument("--plot", default=None, help="write the figure (PNG)")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    if args.threads < 1:
        p.error(f"--threads must be >= 1, got {args.threads}")
    for flag, path in (("--out", args.out), ("--plot", args.plot)):
        if path and not Path(path).resolve().parent.is_dir():
            p.error(f"{flag} {path}: its folder does not exist")
    torch.set_num_threads(args.threads)
    try:
        r = inverse_labels(args.model, args.demos)
    except (ValueError, FileNotFoundError) as err:
        raise SystemExit(f"error: {err}") from None
    print(f"{r['game']} {r['variant']}: {r['pairs']} expert pairs, {r['actions']} actions")
    names = r["action_names"]
    print(f"{'action':>14} {'true':>7} {'label':>7} {'agent':>7}   true actions of the pairs given this label")
    for a in range(r["actions"]):
        col = [r["confusion"][t][a] for t in range(r["actions"])]
        # (only for labels given to at least 0.5 % of the pairs: a handful of pairs says nothing)
        took = (
            sorted(((c / sum(col), names[t]) for t, c in enumerate(col) if c > 0), reverse=True)[:4]
            if sum(col) >= 0.005
            else []
        )
        print(
            f"{a:2d} {names[a]:>11} {r['share_true'][a]:7.1%} {r['share_labels'][a]:7.1%} "
            f"{r['share_agent_greedy'][a]:7.1%}   " + ", ".join(f"{t} {c:.0%}" for c, t in took)
        )
    print(
        f"label accuracy {r['accuracy']:.1%} (the most frequent true action: {r['majority_true_share']:.1%}); "
        f"label = agent's greedy action in {r['labels_equal_agent_greedy']:.1%}; agent's greedy action = expert's "
        f"in {r['agent_greedy_equals_expert']:.1%}; mean confidence {r['mean_confidence']:.2f}"
    )
    for t, g in r["confidence_gate"].items():
        acc = "-" if g["accuracy"] is None else f"{g['accuracy']:.1%}"
        print(f"  loss.bc_confidence={t}: keeps {g['kept']:.1%} of the pairs, their labels' accuracy {acc}")
    if args.out:
        Path(args.out).write_text(json.dumps(r, indent=2))
    if args.plot:
        plot(r, args.plot)
        print(f"figure: {args.plot}")


if __name__ == "__main__":
    main()
