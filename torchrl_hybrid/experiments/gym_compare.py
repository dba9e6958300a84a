"""Variants x seeds of one gymnasium run config (Taxi, FrozenLake, CartPole, ...) on the
TorchRL path (:func:`~torchrl_hybrid.families.gym.train_gym`), then one curve file,
figure, table and README per comparison.

``recipes/compare.py`` is the command line; tests call :func:`run_gym_compare`.
"""

from __future__ import annotations

import csv
import json
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from torchrl_hybrid.experiments.arms import named_arms
from torchrl_hybrid.experiments.study import open_study, planned_run, runs_to_do, study_provenance
from torchrl_hybrid.utils.config import merge_dicts
from torchrl_hybrid.utils.files import read_json
from torchrl_hybrid.utils.launch import LAUNCHERS, run_jobs
from torchrl_hybrid.utils.metrics import IDM_ACCURACY_EXPERT
from torchrl_hybrid.utils.stats import has_interval, mean_ci, mean_diff_ci, permutation_p

__all__ = [
    "GymCompareConfig",
    "run_gym_compare",
    "analyse_gym_compare",
    "random_policy_return",
    "reach_threshold",
]


@dataclass
class GymCompareConfig:
    """What to run: every variant with every seed, each a ``train_gym`` run of
    ``base`` (a :class:`~torchrl_hybrid.families.gym.GymConfig` as nested dicts) in
    ``out_dir/<variant>_s<seed>``. Finished runs are not run again; a run with a
    checkpoint but no summary resumes from it."""

    base: dict = field(default_factory=dict)
    variants: Sequence[str] = (
        "a2c",
        "hybrid_dual",
    )  # variants (torchrl_hybrid/variants.py) or arms (recipes/config/arms/gym.yaml, arms)
    # more named arms: name -> {variant: ..., base: <arm or variant it changes>, <GymConfig overrides>}
    arms: dict = field(default_factory=dict)
    seeds: Sequence[int] = (0, 1, 2)
    out_dir: str = "results/compare"
    workers: int = 2
    launcher: str = "local"  # local (worker processes) | ray (Ray tasks; see torchrl_hybrid/utils/launch.py)
    address: str | None = None  # ray: the cluster to join; None starts a local one
    max_retries: int = 2  # ray: how often a run whose worker died is started again
    command: str = ""  # the command line that made this comparison, for the README
    # runs of out_dir made with other settings than asked now are refused (naming each difference);
    # overwrite=true runs them again with the new settings
    overwrite: bool = False
    # start no run: tabulate the finished runs of variants x seeds (each arm with the seeds it has)
    analyse_only: bool = False

    @property
    def all_arms(self) -> dict[str, dict]:
        return {**named_arms("gym"), **self.arms}

    def run_settings(self, name: str) -> dict:
        """The settings an arm or variant adds to ``base`` (its variant included)."""
        spec = self.all_arms.get(name)
        if spec is None:
            return {"variant": name}
        return {k: v for k, v in spec.items() if k != "base"}

    def validate(self) -> GymCompareConfig:
        from torchrl_hybrid.experiments.arms import check_arms
        from torchrl_hybrid.variants import VARIANTS

        check_arms(self.arms, self.all_arms, VARIANTS, self.variants, "plus GymConfig settings over the base")
        if self.workers < 1:
            raise ValueError(f"compare.workers must be >= 1, got {self.workers}")
        if not self.seeds:
            raise ValueError("compare.seeds is empty")
        if self.launcher not in LAUNCHERS:
            raise ValueError(f"compare.launcher={self.launcher!r}: choose one of {LAUNCHERS}")
        return self


def random_policy_return(
    env_id: str, kwargs: dict | None = None, max_steps: int = 500, episodes: int = 100, seed: int = 0
) -> float:
    """Mean undiscounted return of the uniformly random policy over ``episodes`` episodes,
    each cut at ``max_steps`` (the floor that "X % of the expert" is measured from)."""
    import gymnasium as gym

    env = gym.make(env_id, max_episode_steps=max_steps, **(kwargs or {}))
    env.action_space.seed(seed)
    total = 0.0
    for i in range(episodes):
        env.reset(seed=seed + i)
        done = False
        while not done:
            _, r, term, trunc, _ = env.step(env.action_space.sample())
            total += float(r)
            done = term or trunc
    env.close()
    return total / episodes


#: the share of the way from the random policy's return to the expert's that "frames to X %" asks for
REACH = 0.9


def reach_threshold(random_return: float, expert_return: float, share: float = REACH) -> float:
    """The return ``share`` of the way from the random policy's to the expert's: right for
    negative returns too (``share`` x the expert's return is not: 95 % of Acrobot's -176 is
    -167, a better score than the expert's own)."""
    return random_return + share * (expert_return - random_return)


#: the settings on which a comparison's run must agree with the run of that name already in
#: its folder: those a checkpoint is resumed on, plus the length and the learning curve's points
STUDY_KEYS = ("total_frames", "logger.log_every_frames", "logger.eval_episodes", "logger.final_eval_episodes")


def run_one(d: dict) -> tuple[str, float]:
    """One run of the comparison. Whether it resumes is decided here, when it starts: a
    run restarted after its worker died goes on from its last checkpoint (or starts
    again, replacing its partial files, when it died before the first one). A job with
    ``overwrite`` starts again whatever the folder holds."""
    from torchrl_hybrid.families.gym import config_from_dict, train_gym
    from torchrl_hybrid.utils.process import configure_worker

    configure_worker(d.get("threads"))
    ckpt = not d.get("overwrite") and (Path(d["out_dir"]) / "checkpoint").exists()
    t0 = time.perf_counter()
    train_gym(config_from_dict(merge_dicts(d, {"resume": ckpt, "overwrite": not ckpt})))
    return d["out_dir"], time.perf_counter() - t0


def _looks_like_compare(folder: Path) -> bool:
    """A comparison folder written before ``study.json``: run folders ``<arm>_s<seed>``."""
    return any(
        p.is_dir() and p.name.rpartition("_s")[2].isdigit() and (p / "config.json").exists() for p in folder.iterdir()
    )


def run_gym_compare(cfg: GymCompareConfig, run_fn=run_one) -> dict[str, Any]:
    """Runs the missing runs (``workers`` at a time, on ``cfg.launcher``), then analyses
    them. ``run_fn`` runs one job (:func:`run_one`; the fault tests wrap it). Runs already
    in ``out_dir`` with other settings are refused before anything starts (or, with
    ``cfg.overwrite``, run again)."""
    import dataclasses

    from torchrl_hybrid.families.gym import _RESUME_KEYS, GymConfig, config_from_dict

    cfg.validate()
    # a progress bar only where one run trains in this terminal, and only if the settings ask for it
    bar = cfg.base.get("logger", {}).get("progress_bar", True) and cfg.workers == 1 and cfg.launcher == "local"
    planned = []
    for variant in cfg.variants:
        for seed in cfg.seeds:
            out = Path(cfg.out_dir) / f"{variant}_s{seed}"
            d = merge_dicts(
                merge_dicts(cfg.base, cfg.run_settings(variant)),
                {"seed": seed, "out_dir": str(out), "logger": {"progress_bar": bar}},
            )
            planned.append(planned_run(f"{variant}_s{seed}", out, d, config_from_dict))
    with open_study(cfg.out_dir, "gym_compare", looks_like=_looks_like_compare, overwrite=cfg.overwrite) as study:
        if cfg.analyse_only:
            todo = [name for name, out, _, _ in planned if not (out / "summary.json").exists()]
            print(
                f"analyse_only: {len(todo)} run(s) not finished, left out" + (f": {', '.join(todo)}" if todo else ""),
                flush=True,
            )
            return analyse_gym_compare(cfg)
        named, changed = runs_to_do(
            planned,
            cfg.out_dir,
            _RESUME_KEYS + STUDY_KEYS,
            ignore=("logger.progress_bar",),
            defaults=dataclasses.asdict(GymConfig()),
            overwrite=cfg.overwrite,
        )
        jobs = [d for _, d in named]
        if jobs:
            study.record_session()
        print(
            f"{len(jobs)} run(s) to do in {cfg.out_dir}"
            + (" on Ray" if cfg.launcher == "ray" else "")
            + (f" ({len(changed)} again with the new settings)" if changed else ""),
            flush=True,
        )
        t0 = time.perf_counter()
        for out, secs in run_jobs(
            run_fn, jobs, launcher=cfg.launcher, workers=cfg.workers, address=cfg.address, max_retries=cfg.max_retries
        ):
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
                rows = [
                    {k: float(v) if v not in ("", None) else math.nan for k, v in r.items()} for r in csv.DictReader(f)
                ]
            runs.setdefault(variant, []).append(
                {"seed": seed, "rows": rows, "summary": read_json(d / "summary.json", "run summary")}
            )
    return runs


def _diff_text(a: np.ndarray, b: np.ndarray) -> str:
    """mean(a) - mean(b) with its bootstrap interval and permutation p; the difference alone
    where either side has fewer seeds than an interval needs."""
    if not has_interval(a, b):
        return f"{np.mean(a) - np.mean(b):+.2f} (no interval: {len(a)} vs {len(b)} seeds)"
    d, lo, hi = mean_diff_ci(a, b)
    return f"{d:+.2f} [{lo:+.2f}, {hi:+.2f}], p = {permutation_p(a, b):.3f}"


def _ci_text(x: np.ndarray, digits: int = 2) -> str:
    if not has_interval(x):
        return f"{np.mean(x):.{digits}f}"
    m, lo, hi = mean_ci(x)
    return f"{m:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def analyse_gym_compare(cfg: GymCompareConfig, wall_time_s: float | None = None) -> dict[str, Any]:
    """Per variant: the greedy-return curves, ``auc`` (mean greedy return over the logged
    points), ``final`` (the end-of-run greedy return), frames until 90 % of the way from the random
    policy's return to the expert's (:func:`reach_threshold`), the inverse model's accuracy on the
    expert pairs and the policy's entropy at the end; each variant against the first, and each
    named arm against the arm it changes, with a bootstrap interval and a permutation p-value. Writes ``curves.csv``, ``summary.csv``, ``comparison.png``, ``README.md``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = _load(cfg)
    if not runs:
        raise ValueError(f"no finished runs in {cfg.out_dir}")
    out = Path(cfg.out_dir)
    optimal = [
        r["summary"]["optimal_return"] for rs in runs.values() for r in rs if r["summary"]["optimal_return"] is not None
    ]
    optimal = float(np.mean(optimal)) if optimal else None
    env_cfg = {**{"env_id": "Taxi-v4", "kwargs": {}, "max_episode_steps": 50}, **cfg.base.get("env", {})}
    random_return = random_policy_return(env_cfg["env_id"], env_cfg["kwargs"], env_cfg["max_episode_steps"])
    # "X % of the expert" from the random policy's return up (right for negative returns too: 95 % of
    # Acrobot's -176 is -167, better than the expert; 90 % of the way from -500 to -176 is -208)
    threshold = None if optimal is None else reach_threshold(random_return, optimal)
    stats: dict[str, dict] = {}
    with open(out / "curves.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["variant", "seed", "frames", "eval_return", "return_mean", IDM_ACCURACY_EXPERT, "entropy"])
        for variant, rs in runs.items():
            for r in rs:
                for row in r["rows"]:
                    w.writerow(
                        [
                            variant,
                            r["seed"],
                            int(row["frames"]),
                            row.get("eval_return", math.nan),
                            row.get("return_mean", math.nan),
                            row.get(IDM_ACCURACY_EXPERT, ""),
                            row.get("entropy", ""),
                        ]
                    )
    has_acc = any(
        not math.isnan(row.get(IDM_ACCURACY_EXPERT, math.nan)) for rs in runs.values() for r in rs for row in r["rows"]
    )
    fig, axes = plt.subplots(1, 2 if has_acc else 1, figsize=(12 if has_acc else 6.5, 4.2), squeeze=False)
    for ci, (variant, rs) in enumerate(runs.items()):
        n = min(len(r["rows"]) for r in rs)
        frames = np.array([row["frames"] for row in rs[0]["rows"][:n]])
        ev = np.array([[row["eval_return"] for row in r["rows"][:n]] for r in rs])
        reach = []
        for c in ev:
            hit = np.nonzero(c >= threshold)[0] if threshold is not None else []
            reach.append(float(frames[hit[0]]) if len(hit) else math.nan)

        def last(r, key):
            vals = [row[key] for row in r["rows"] if not math.isnan(row.get(key, math.nan))]
            return vals[-1] if vals else math.nan

        stats[variant] = {
            "seeds": [r["seed"] for r in rs],
            "auc": ev.mean(1),
            "final": np.array([r["summary"]["final_return"] for r in rs]),
            "reach": np.array(reach),
            "budget": float(frames[-1]),
            "idm_acc": np.array([last(r, IDM_ACCURACY_EXPERT) for r in rs]),
            "entropy": np.array([last(r, "entropy") for r in rs]),
            "frames_per_s": float(np.mean([r["summary"]["frames_per_s"] for r in rs])),
        }
        ax = axes[0, 0]
        for c in ev:
            ax.plot(frames, c, color=f"C{ci}", lw=0.7, alpha=0.35)
        ax.plot(frames, ev.mean(0), color=f"C{ci}", lw=2, label=f"{variant} ({len(rs)} seeds)")
        if has_acc:
            for k, r in enumerate(rs):
                pts = [
                    (row["frames"], row[IDM_ACCURACY_EXPERT])
                    for row in r["rows"]
                    if not math.isnan(row.get(IDM_ACCURACY_EXPERT, math.nan))
                ]
                if pts:
                    axes[0, 1].plot(*zip(*pts), color=f"C{ci}", lw=1, label=variant if k == 0 else None)
    env_name = cfg.base.get("env", {}).get("env_id", "Taxi-v4")
    ax = axes[0, 0]
    if optimal is not None:
        ax.axhline(optimal, color="k", ls="--", lw=1, label=f"expert {optimal:.2f}")
        ax.axhline(threshold, color="k", ls=":", lw=1, label=f"{REACH:.0%} of the way from random {random_return:.1f}")
    ax.set(xlabel="frames", ylabel="greedy return", title=f"{env_name}: mean (thick) and each seed (thin)")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    if has_acc:
        axes[0, 1].set(
            xlabel="frames",
            ylabel="inferred = true expert action",
            ylim=(0, 1.03),
            title="inverse-model accuracy on the demo pairs",
        )
        axes[0, 1].grid(alpha=0.3)
        axes[0, 1].legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "comparison.png", dpi=110)
    plt.close(fig)

    ref = cfg.variants[0] if cfg.variants[0] in stats else next(iter(stats))
    pct = f"{REACH:.0%}"
    table = []
    for variant, s in stats.items():
        # frames to the threshold, a seed that never reached it counted as the whole budget (a lower bound)
        censored = np.where(np.isfinite(s["reach"]), s["reach"], s["budget"])
        row = {
            "variant": variant,
            "seeds": len(s["seeds"]),
            "auc": _ci_text(s["auc"]),
            "final": _ci_text(s["final"]),
            "reached": f"{int(np.isfinite(s['reach']).sum())}/{len(s['reach'])}",
            "frames_to_reach": _ci_text(censored, digits=0) if threshold is not None else "",
            "idm_accuracy_expert_end": "" if np.isnan(s["idm_acc"]).all() else f"{np.nanmean(s['idm_acc']):.2f}",
            "entropy_end": "" if np.isnan(s["entropy"]).all() else f"{np.nanmean(s['entropy']):.2f}",
            "auc_per_seed": [round(float(x), 2) for x in s["auc"]],
            "final_per_seed": [round(float(x), 2) for x in s["final"]],
            "frames_per_s": round(s["frames_per_s"], 1),
        }
        if variant != ref:
            row[f"auc_minus_{ref}"] = _diff_text(s["auc"], stats[ref]["auc"])
        base = cfg.all_arms.get(variant, {}).get("base")
        if base in stats:
            row["option_effect"] = f"auc − {base}: " + _diff_text(s["auc"], stats[base]["auc"])
        table.append(row)
    raw = {
        "env_id": env_name,
        "expert_return": optimal,
        "random_return": random_return,
        "threshold": threshold,
        "reach_share": REACH,
        "reference": ref,
        "arms": {
            v: {
                "variant": cfg.run_settings(v)["variant"],
                "base": cfg.all_arms.get(v, {}).get("base"),
                "rl": cfg.run_settings(v).get("rl", cfg.base.get("rl", "a2c")),
                "seeds": st["seeds"],
                "auc": st["auc"].tolist(),
                "final": st["final"].tolist(),
                "frames_to_reach": [None if not np.isfinite(x) else float(x) for x in st["reach"]],
                "budget": st["budget"],
                "idm_accuracy_expert_end": [None if np.isnan(x) else float(x) for x in st["idm_acc"]],
                "entropy_end": [None if np.isnan(x) else float(x) for x in st["entropy"]],
            }
            for v, st in stats.items()
        },
    }
    (out / "summary.json").write_text(json.dumps(raw, indent=2))
    with open(out / "summary.csv", "w", newline="") as f:
        w = csv.DictWriter(
            f,
            fieldnames=sorted(
                {k for t in table for k in t}, key=lambda k: list(table[0]).index(k) if k in table[0] else 99
            ),
        )
        w.writeheader()
        w.writerows(table)
    lines = [f"# {env_name}: {' vs '.join(stats)}", ""]
    if cfg.command:
        lines += [
            f"Rerun: `{cfg.command}`"
            + (f" ({wall_time_s / 60:.1f} min on the 2-core CPU machine)" if wall_time_s else ""),
            "",
        ]
    made = study_provenance(out)
    if made:
        lines += [made, ""]
    lines += [
        "Greedy return of the policy (mode of its distribution) on fresh episodes at every logged point; "
        "`auc` is its mean over the logged points, `final` the greedy return at the end of the run, "
        f"`reached` the seeds whose greedy return reached {pct} of the way from the random policy's return "
        f"({random_return:.2f}) to the expert's"
        + (f" ({optimal:.2f}): {threshold:.2f}" if optimal is not None else " (no expert return: none was given)")
        + f"; `frames to {pct}` their mean, a seed that never reached it counted as the whole budget "
        "(so a lower bound). `IDM acc.` is the inverse model's accuracy on the expert pairs at the end (where "
        "the demos keep the true actions), `entropy` the policy's at the end (a collapse shows as ~0). "
        "Intervals: bootstrap 95 % over seeds (3 or more seeds); differences against "
        f"`{ref}`, and each named arm against the arm it changes, with a permutation-test p-value.",
        "",
        f"| arm | seeds | auc | final | reached | frames to {pct} | IDM acc. | entropy | auc − {ref} | option |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for t in table:
        lines.append(
            f"| {t['variant']} | {t['seeds']} | {t['auc']} | {t['final']} | {t['reached']} | "
            f"{t['frames_to_reach'] or '-'} | {t['idm_accuracy_expert_end'] or '-'} | {t['entropy_end'] or '-'} | "
            f"{t.get(f'auc_minus_{ref}', '-')} | {t.get('option_effect', '-')} |"
        )
    lines += [
        "",
        "![comparison](comparison.png)",
        "",
        "Files: `curves.csv` (every logged point of every run), `summary.csv`, and each run's folder "
        "(`metrics.csv`, `summary.json`, `config.json`, `learning_curve.png`).",
    ]
    (out / "README.md").write_text("\n".join(lines) + "\n")
    for t in table:
        print(
            f"{t['variant']:12s} seeds {t['seeds']}  auc {t['auc']}  final {t['final']}  reached {pct} "
            f"{t['reached']}  {t.get(f'auc_minus_{ref}', '')}"
        )
    return {"table": table, "optimal": optimal, "random_return": random_return, "threshold": threshold}
