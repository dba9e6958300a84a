"""One table over every env's comparison (the README's headline): the RL base, the paper's
hybrid, the best arm with inferred labels, and the oracle, from each comparison's
``summary.json`` (written by :func:`~torchrl_hybrid.experiments.gym_compare.analyse_gym_compare`).

``recipes/headline.py`` is the command line; it rewrites the README block between
``<!-- headline:start -->`` and ``<!-- headline:end -->``.

The issue's goals, per env, for the best arm with inferred labels:

- *faster*: it reaches 90 % of the way from the random policy's return to the expert's in at
  most half the frames its RL base needs (a seed that never reaches it counts as the whole
  budget), or it reaches it in every seed where the base reaches it in none;
- *labels as good as true ones*: its AUC is inside the oracle arm's 95 % interval, or above.

Where a goal is missed, the decomposition says which part is at fault: the oracle against the
RL base is the objective's, the best inferred arm against the oracle is the labels'.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from torchrl_hybrid.utils.files import read_json
from torchrl_hybrid.utils.stats import has_interval, mean_ci, mean_diff_ci, permutation_p

__all__ = ["headline_rows", "headline_markdown", "update_readme_block"]

START, END = "<!-- headline:start -->", "<!-- headline:end -->"


def _frames(arm: dict) -> np.ndarray:
    return np.array([arm["budget"] if f is None else f for f in arm["frames_to_reach"]], float)


def _reached(arm: dict) -> int:
    return sum(f is not None for f in arm["frames_to_reach"])


def _ci(x) -> str:
    x = np.asarray(x, float)
    if not has_interval(x):
        return f"{x.mean():.1f}"
    m, lo, hi = mean_ci(x)
    return f"{m:.1f} [{lo:.1f}, {hi:.1f}]"


#: per RL base: the arm that is the base alone and the paper's hybrid on it (recipes/config/arms/gym.yaml's names)
BASES = {"a2c": ("a2c", "hybrid_dual"), "ppo": ("ppo", "hybrid_dual_ppo")}


def _rl(name: str, arm: dict) -> str:
    """An arm's RL base; summaries written before they stored it name it by the arms' suffix."""
    return arm.get("rl") or ("ppo" if name == "ppo" or name.endswith("_ppo") else "a2c")


def headline_rows(studies: dict[str, str | Path], oracle: str = "hybrid_true") -> list[dict[str, Any]]:
    """One row per env and RL base run there (``a2c``, ``ppo``): ``studies`` maps an env's label
    to its comparison's out_dir. Each row holds the arms on that base only (their ``rl``)."""
    rows = []
    for label, out_dir in studies.items():
        summary = read_json(Path(out_dir) / "summary.json", "comparison summary (recipes/compare.py rewrites it)")
        all_arms = summary["arms"]
        bases = [rl for rl, (name, _) in BASES.items() if name in all_arms]
        if not bases:
            raise ValueError(
                f"{out_dir}: no RL-base runs ({' or '.join(n for n, _ in BASES.values())}) to compare against"
            )
        for rl in bases:
            base, paper = BASES[rl]
            arms = {k: a for k, a in all_arms.items() if _rl(k, a) == rl}
            rows.append(
                _row(
                    f"{label}" if len(bases) == 1 else f"{label}, {rl.upper()}",
                    out_dir,
                    summary,
                    arms,
                    base,
                    paper,
                    oracle,
                    rl,
                )
            )
    return rows


def _row(label: str, out_dir, summary: dict, arms: dict, base: str, paper: str, oracle: str, rl: str) -> dict:
    b = arms[base]
    inferred = {k: a for k, a in arms.items() if a["variant"] in ("hybrid_dual", "hybrid_mlp")}
    best_name = max(inferred, key=lambda k: np.mean(inferred[k]["auc"])) if inferred else None
    row: dict[str, Any] = {
        "env": label,
        "rl": rl,
        "out_dir": str(out_dir),
        "expert": summary["expert_return"],
        "base_arm": base,
        "base": _ci(b["auc"]),
        "base_reached": f"{_reached(b)}/{len(b['auc'])}",
        "base_frames": float(_frames(b).mean()),
    }
    # the oracle to hold the best arm against: its counterpart with true labels and the same settings
    # (hybrid_dual_X -> hybrid_true_X), else the strongest oracle arm run (the harder bar)
    oracles = {k: a for k, a in arms.items() if a["variant"] == oracle}
    twin = best_name.replace("hybrid_dual", oracle, 1) if best_name else None
    oracle_name = (
        twin if twin in oracles else (max(oracles, key=lambda k: np.mean(oracles[k]["auc"])) if oracles else oracle)
    )
    for key, name in (("paper", paper), ("best", best_name), ("oracle", oracle_name)):
        a = arms.get(name)
        if a is None:
            row[key] = None
            continue
        d, lo, hi = mean_diff_ci(a["auc"], b["auc"]) if has_interval(a["auc"], b["auc"]) else (np.nan,) * 3
        p = permutation_p(a["auc"], b["auc"]) if has_interval(a["auc"], b["auc"]) else np.nan
        row[key] = {
            "arm": name,
            "auc": _ci(a["auc"]),
            "diff": f"{d:+.1f} [{lo:+.1f}, {hi:+.1f}], p = {p:.2f}",
            "reached": f"{_reached(a)}/{len(a['auc'])}",
            "frames": float(_frames(a).mean()),
            "auc_mean": float(np.mean(a["auc"])),
            "auc_values": a["auc"],
        }
    best, orc = row["best"], row["oracle"]
    if best is not None:
        never = _reached(b) == 0 and _reached(arms[best_name]) == len(arms[best_name]["auc"])
        row["faster"] = bool(never or best["frames"] <= 0.5 * row["base_frames"])
        if orc is not None and has_interval(orc["auc_values"]):
            _, lo, _ = mean_ci(orc["auc_values"])
            row["as_good_as_true"] = bool(best["auc_mean"] >= lo)
        else:
            row["as_good_as_true"] = None
    return row


def headline_markdown(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| env | RL base: AUC | paper's hybrid AUC (− base) | best inferred-label arm: AUC (− base) | "
        "its oracle: AUC | frames to 90 %: base / best | faster? | labels as good as true? |",
        "|---|---|---|---|---|---|---|---|",
    ]

    def cell(x, full=True):
        if x is None:
            return "not run"
        return f"{x['auc']} ({x['diff']})" if full else x["auc"]

    for r in rows:
        best = r["best"]
        frames = (
            f"{r['base_frames'] / 1e3:.0f}k ({r['base_reached']}) / {best['frames'] / 1e3:.0f}k ({best['reached']})"
            if best
            else "-"
        )
        yes = {True: "**yes**", False: "no", None: "-"}
        lines.append(
            f"| [{r['env']}]({r['out_dir']}/README.md) | `{r['base_arm']}`: {r['base']} | {cell(r['paper'])} | "
            f"{'`' + best['arm'] + '`: ' + cell(best) if best else '-'} | "
            f"{'`' + r['oracle']['arm'] + '`: ' + r['oracle']['auc'] if r['oracle'] else 'not run'} | "
            f"{frames} | {yes[r.get('faster')]} | {yes[r.get('as_good_as_true')]} |"
        )
    return "\n".join(lines)


def update_readme_block(readme: str | Path, table: str) -> None:
    """Replaces the README's headline block with ``table``."""
    path = Path(readme)
    text = path.read_text()
    if START not in text or END not in text:
        raise ValueError(f"{path} has no {START} ... {END} block to write the headline table into")
    head, rest = text.split(START, 1)
    _, tail = rest.split(END, 1)
    path.write_text(f"{head}{START}\n{table}\n{END}{tail}")
