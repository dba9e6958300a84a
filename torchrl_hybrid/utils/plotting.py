"""Figures."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

__all__ = ["plot_learning_curve"]


def plot_learning_curve(rows: Sequence[dict], path: str | Path, title: str = "", optimal: float | None = None) -> Path:
    """Returns (training and greedy evaluation) and inverse-model accuracy vs frames."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    frames = [r["frames"] for r in rows]
    key = "idm_accuracy_expert"  # the inferred label equals the expert's true action (NaN: demos without actions)
    if not any(not math.isnan(r.get(key, math.nan)) for r in rows):
        key = "idm_accuracy"  # otherwise the loss's accuracy on the agent's own batches
    has_acc = any(not math.isnan(r.get(key, math.nan)) for r in rows)
    fig, axes = plt.subplots(1, 2 if has_acc else 1, figsize=(11 if has_acc else 6, 4), squeeze=False)
    ax = axes[0, 0]
    for key, label in (("return_mean", "training episodes"), ("eval_return", "greedy evaluation")):
        pts = [(f, r[key]) for f, r in zip(frames, rows) if key in r and not math.isnan(r[key])]
        if pts:
            ax.plot(*zip(*pts), label=label)
    if optimal is not None:
        ax.axhline(optimal, color="k", ls="--", lw=1, label=f"optimal ({optimal:.2f})")
    ax.set_xlabel("frames")
    ax.set_ylabel("undiscounted return")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="lower right")
    ax.grid(alpha=0.3)
    ax.set_title(title)
    if has_acc:
        ax = axes[0, 1]
        pts = [(f, r[key]) for f, r in zip(frames, rows) if not math.isnan(r.get(key, math.nan))]
        ax.plot(*zip(*pts), color="C2")
        ax.set_ylim(0, 1)
        ax.set_xlabel("frames")
        if key == "idm_accuracy_expert":
            ax.set_ylabel("inferred = true expert action")
            ax.set_title("inverse-model accuracy on the demo pairs")
        else:
            ax.set_ylabel("inferred = the agent's action")
            ax.set_title("inverse-model accuracy on the agent's batches")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
