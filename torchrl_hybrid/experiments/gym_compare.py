"""Variants x seeds of one gymnasium run config (Taxi, FrozenLake, CartPole, ...) on the
TorchRL path (:func:`~torchrl_hybrid.trainers.taxi.train_taxi`), then one curve file,
figure, table and README per comparison.

``recipes/compare.py`` is the command line; tests call :func:`run_gym_compare`.
"""
from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from torchrl_hybrid.utils.config import merge_dicts
from torchrl_hybrid.utils.launch import LAUNCHERS, run_jobs
from torchrl_hybrid.utils.metrics import IDM_ACCURACY_EXPERT
from torchrl_hybrid.utils.stats import mean_ci, mean_diff_ci, permutation_p

__all__ = ["GymCompareConfig", "run_gym_compare", "analyse_gym_compare"]


@dataclass
class GymCompareConfig:
    """What to run: every variant with every seed, each a ``train_taxi`` run of
    ``base`` (a :class:`~torchrl_hybrid.trainers.taxi.TaxiConfig` as nested dicts) in
    ``out_dir/<variant>_s<seed>``. Finished runs are not run again; a run with a
    checkpoint but no summary resumes from it."""

    base: dict = field(default_factory=dict)
    variants: Sequence[str] = ("a2c", "hybrid_dual")
    seeds: Sequence[int] = (0, 1, 2)
    out_dir: str = "results/compare"
    workers: int = 2
    launcher: str = "local"     # local (worker processes) | ray (Ray tasks; see torchrl_hybrid/utils/launch.py)
    address: str | None = None  # ray: the cluster to join; None starts a local one
    max_retries: int = 2        # ray: how often a run whose worker died is started again
    command: str = ""  # the command line that made this comparison, for the README

    def validate(self) -> "GymCompareConfig":
        from torchrl_hybrid.trainers.hybrid import get_variant

        for v in self.variants:
            get_variant(v)
        if self.workers < 1:
            raise ValueError(f"compare.workers must be >= 1, got {self.workers}")
        if not self.seeds:
            raise ValueError("compare.seeds is empty")
        if self.launcher not in LAUNCHERS:
            raise ValueError(f"compare.launcher={self.launcher!r}: choose one of {LAUNCHERS}")
        return self



def run_one(d: dict) -> tuple[str, float]:
    """One run of the comparison. Whether it resumes is decided here, when it starts: a
    run restarted after its worker died goes on from its last checkpoint (or starts
    again, replacing its partial files, when it died before the first one)."""
    from torchrl_hybrid.trainers.taxi import config_from_dict, train_taxi
    from torchrl_hybrid.utils.process import configure_worker

    configure_worker(d.get("threads"))
    ckpt = (Path(d["out_dir"]) / "checkpoint").exists()
    t0 = time.perf_counter()
    train_taxi(config_from_dict(merge_dicts(d, {"resume": ckpt, "overwrite": not ckpt})))
    return d["out_dir"], time.perf_counter() - t0


def run_gym_compare(cfg: GymCompareConfig, run_fn=run_one) -> dict[str, Any]:
    """Runs the missing runs (``workers`` at a time, on ``cfg.launcher``), then analyses
    them. ``run_fn`` runs one job (:func:`run_one`; the fault tests wrap it)."""
    cfg.validate()
    jobs = []
    for variant in cfg.variants:
        for seed in cfg.seeds:
            out = Path(cfg.out_dir) / f"{variant}_s{seed}"
            if (out / "summary.json").exists():
                continue
            # a progress bar only where one run trains in this terminal, and only if the settings ask for it
            bar = cfg.base.get("logger", {}).get("progress_bar", True) and cfg.workers == 1 and cfg.launcher == "local"
            jobs.append(merge_dicts(cfg.base, {"variant": variant, "seed": seed, "out_dir": str(out),
                                               "logger": {"progress_bar": bar}}))
    print(f"{len(jobs)} run(s) to do in {cfg.out_dir}" + (" on Ray" if cfg.launcher == "ray" else ""), flush=True)
    t0 = time.perf_counter()
    for out, secs in run_jobs(run_fn, jobs, launcher=cfg.launcher, workers=cfg.workers, address=cfg.address,
                              max_retries=cfg.max_retries):
        print(f"  {out}: {secs:.0f} s ({time.perf_counter() - t0:.0f} s since start)", flush=True)
    return analyse_gym_compare(cfg, wall_time_s=time.perf_counter() - t0 if jobs else None)


def _load(cfg: GymCompareConfig) -> dict[str, list[dict]]:
    runs: dict[str, list[dict]] = {}
    for variant in cfg.variants:
        for seed in cfg.seeds:
            d = Path(cfg.out_dir) / f"{variant}_s{seed}"
            if not (d / "summary.json").exists():
                continue
            with open(d / "metrics.csv") as f:
                rows = [{k: float(v) if v not in ("", None) else math.nan for k, v in r.items()}
                        for r in csv.DictReader(f)]
            runs.setdefault(variant, []).append(
                {"seed": seed, "rows": rows, "summary": json.loads((d / "summary.json").read_text())})
    return runs


def _ci_text(x: np.ndarray) -> str:
    if len(x) < 3:
        return f"{np.mean(x):.2f}"
    m, lo, hi = mean_ci(x)
    return f"{m:.2f} [{lo:.2f}, {hi:.2f}]"


def analyse_gym_compare(cfg: GymCompareConfig, wall_time_s: float | None = None) -> dict[str, Any]:
    """Per variant: the greedy-return curves, ``auc`` (mean greedy return over the logged
    points), ``final`` (the end-of-run greedy return), frames until 95 % of the expert's
    return; each variant against the first with a bootstrap interval and a permutation
    p-value. Writes ``curves.csv``, ``summary.csv``, ``comparison.png``, ``README.md``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = _load(cfg)
    if not runs:
        raise ValueError(f"no finished runs in {cfg.out_dir}")
    out = Path(cfg.out_dir)
    optimal = [r["summary"]["optimal_return"] for rs in runs.values() for r in rs
               if r["summary"]["optimal_return"] is not None]
    optimal = float(np.mean(optimal)) if optimal else None
    stats: dict[str, dict] = {}
    with open(out / "curves.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["variant", "seed", "frames", "eval_return", "return_mean", IDM_ACCURACY_EXPERT])
        for variant, rs in runs.items():
            for r in rs:
                for row in r["rows"]:
                    w.writerow([variant, r["seed"], int(row["frames"]), row.get("eval_return", math.nan),
                                row.get("return_mean", math.nan), row.get(IDM_ACCURACY_EXPERT, "")])
    has_acc = any(not math.isnan(row.get(IDM_ACCURACY_EXPERT, math.nan)) for rs in runs.values() for r in rs
                  for row in r["rows"])
    fig, axes = plt.subplots(1, 2 if has_acc else 1, figsize=(12 if has_acc else 6.5, 4.2), squeeze=False)
    for ci, (variant, rs) in enumerate(runs.items()):
        n = min(len(r["rows"]) for r in rs)
        frames = np.array([row["frames"] for row in rs[0]["rows"][:n]])
        ev = np.array([[row["eval_return"] for row in r["rows"][:n]] for r in rs])
        reach = []
        for c in ev:
            hit = np.nonzero(c >= 0.95 * optimal)[0] if optimal is not None else []
            reach.append(float(frames[hit[0]]) if len(hit) else math.nan)
        stats[variant] = {"seeds": [r["seed"] for r in rs], "auc": ev.mean(1),
                          "final": np.array([r["summary"]["final_return"] for r in rs]), "reach": np.array(reach),
                          "frames_per_s": float(np.mean([r["summary"]["frames_per_s"] for r in rs]))}
        ax = axes[0, 0]
        for c in ev:
            ax.plot(frames, c, color=f"C{ci}", lw=0.7, alpha=0.35)
        ax.plot(frames, ev.mean(0), color=f"C{ci}", lw=2, label=f"{variant} ({len(rs)} seeds)")
        if has_acc:
            for k, r in enumerate(rs):
                pts = [(row["frames"], row[IDM_ACCURACY_EXPERT]) for row in r["rows"]
                       if not math.isnan(row.get(IDM_ACCURACY_EXPERT, math.nan))]
                if pts:
                    axes[0, 1].plot(*zip(*pts), color=f"C{ci}", lw=1, label=variant if k == 0 else None)
    env_name = cfg.base.get("env", {}).get("env_id", "Taxi-v4")
    ax = axes[0, 0]
    if optimal is not None:
        ax.axhline(optimal, color="k", ls="--", lw=1, label=f"expert {optimal:.2f}")
    ax.set(xlabel="frames", ylabel="greedy return", title=f"{env_name}: mean (thick) and each seed (thin)")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    if has_acc:
        axes[0, 1].set(xlabel="frames", ylabel="inferred = true expert action", ylim=(0, 1.03),
                       title="inverse-model accuracy on the demo pairs")
        axes[0, 1].grid(alpha=0.3)
        axes[0, 1].legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "comparison.png", dpi=110)
    plt.close(fig)

    ref = cfg.variants[0] if cfg.variants[0] in stats else next(iter(stats))
    table = []
    for variant, s in stats.items():
        row = {"variant": variant, "seeds": len(s["seeds"]), "auc": _ci_text(s["auc"]),
               "final": _ci_text(s["final"]),
               "reached_95pct": f"{int(np.isfinite(s['reach']).sum())}/{len(s['reach'])}",
               "median_frames_to_95pct": "" if not np.isfinite(s["reach"]).any()
               else f"{np.nanmedian(s['reach']):.0f}",
               "auc_per_seed": [round(float(x), 2) for x in s["auc"]],
               "final_per_seed": [round(float(x), 2) for x in s["final"]],
               "frames_per_s": round(s["frames_per_s"], 1)}
        if variant != ref and min(len(s["auc"]), len(stats[ref]["auc"])) >= 2:
            d, lo, hi = mean_diff_ci(s["auc"], stats[ref]["auc"])
            row[f"auc_minus_{ref}"] = f"{d:+.2f} [{lo:+.2f}, {hi:+.2f}], p = {permutation_p(s['auc'], stats[ref]['auc']):.3f}"
        table.append(row)
    with open(out / "summary.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=sorted({k for t in table for k in t}, key=lambda k: list(table[0]).index(k)
                                                if k in table[0] else 99))
        w.writeheader()
        w.writerows(table)
    lines = [f"# {env_name}: {' vs '.join(stats)}", ""]
    if cfg.command:
        lines += [f"Rerun: `{cfg.command}`" + (f" ({wall_time_s / 60:.1f} min on the 2-core CPU machine)"
                                               if wall_time_s else ""), ""]
    lines += ["Greedy return of the policy (mode of its distribution) on fresh episodes at every logged point; "
              "`auc` is its mean over the logged points, `final` the greedy return at the end of the run, "
              "`reached 95 %` the seeds whose greedy return reached 95 % of the expert's "
              + (f"({0.95 * optimal:.2f}; the expert's own greedy return is {optimal:.2f})" if optimal is not None
                 else "(no expert return: none was given)")
              + ". Intervals: bootstrap 95 % over seeds (3 or more seeds); differences against "
              f"`{ref}` with a permutation-test p-value.", "",
              "| variant | seeds | auc | final | reached 95 % | median frames to 95 % | auc − " + ref + " |",
              "|---|---|---|---|---|---|---|"]
    for t in table:
        lines.append(f"| {t['variant']} | {t['seeds']} | {t['auc']} | {t['final']} | {t['reached_95pct']} | "
                     f"{t['median_frames_to_95pct'] or '-'} | {t.get(f'auc_minus_{ref}', '-')} |")
    lines += ["", "![comparison](comparison.png)", "",
              "Files: `curves.csv` (every logged point of every run), `summary.csv`, and each run's folder "
              "(`metrics.csv`, `summary.json`, `config.json`, `learning_curve.png`)."]
    (out / "README.md").write_text("\n".join(lines) + "\n")
    for t in table:
        print(f"{t['variant']:12s} seeds {t['seeds']}  auc {t['auc']}  final {t['final']}  reached 95 % "
              f"{t['reached_95pct']}  {t.get(f'auc_minus_{ref}', '')}")
    return {"table": table, "optimal": optimal}
