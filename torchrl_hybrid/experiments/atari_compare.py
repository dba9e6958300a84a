"""Atari comparison: variants x seeds on one or more games, then curves, a figure
and a summary table per game.

``recipes/atari_compare.py`` is the command line. Each run is an ordinary
:func:`~torchrl_hybrid.families.atari.train_atari` run in ``<out_dir>/<game>/<variant>_s<seed>``;
a run whose ``summary.json`` exists is not run again, and an unfinished one goes
on from its last checkpoint (every tenth of its frames), so a sweep interrupted at
the end of a session picks up where it stopped. The tables and figures describe every
finished run in the folder, so sweeps of a few arms or seeds at a time add up.
"""

from __future__ import annotations

import csv
import json
import math
import threading
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from torchrl_hybrid.experiments.arms import named_arms
from torchrl_hybrid.experiments.study import open_study, planned_run, runs_to_do, study_provenance
from torchrl_hybrid.utils.config import flatten_dict, merge_dicts
from torchrl_hybrid.utils.files import read_json
from torchrl_hybrid.utils.launch import LAUNCHERS, run_jobs
from torchrl_hybrid.utils.metrics import IDM_ACCURACY_AGENT, IDM_ACCURACY_EXPERT, upgrade_accuracy_keys
from torchrl_hybrid.utils.stats import has_interval, mean_ci, mean_diff_ci, permutation_p

__all__ = [
    "CompareConfig",
    "SweepProgress",
    "run_compare",
    "analyse_compare",
    "load_runs",
    "option_effects",
    "option_text",
    "overview_figure",
    "effects_figure",
]


@dataclass
class CompareConfig:
    """What to run. ``demos`` maps a game to its demo folder (needed by every
    variant but ``a2c``); ``base`` holds :class:`AtariConfig` overrides for every run;
    ``baselines`` maps a label to another comparison's ``out_dir`` whose finished runs
    of the same games are drawn and tabulated beside these (as ``<variant> (<label>)``),
    without being run again. ``arms`` maps a name to ``{"variant": <variant>, **overrides}``
    beside the named arms of ``recipes/config/arms/atari.yaml`` (with an optional ``base: <arm or variant>``, the arm it adds
    one option to: see :func:`option_effects`); a name in ``variants`` that is not a variant is an arm."""

    games: Sequence[str] = ("Pong", "Breakout")
    variants: Sequence[str] = ("a2c", "hybrid_dual")
    seeds: Sequence[int] = (0, 1)
    total_frames: int = 2_000_000
    # a fresh folder per comparison unless named (results/... is regenerated only when asked for)
    out_dir: str = field(default_factory=lambda: time.strftime("outputs/atari_compare/%Y-%m-%d_%H-%M-%S"))
    demos: dict = field(default_factory=dict)
    workers: int = 2
    base: dict = field(default_factory=dict)
    baselines: dict = field(default_factory=dict)
    label: str = ""  # shown after this comparison's variant names when baselines are drawn beside
    launcher: str = "local"  # local (worker processes) | ray (Ray tasks; see torchrl_hybrid/utils/launch.py)
    address: str | None = None  # ray: the cluster to join; None starts a local one
    max_retries: int = 2  # ray: how often a run whose worker died is started again
    arms: dict = field(default_factory=dict)  # more named arms, beside (or replacing) recipes/config/arms/atari.yaml's
    analyse_only: bool = False  # start no run: draw and tabulate the finished ones (demos not needed)
    # runs of out_dir made with other settings than asked now are refused (naming each difference);
    # overwrite=true runs them again with the new settings
    overwrite: bool = False

    @property
    def all_arms(self) -> dict[str, dict]:
        return {**named_arms("atari"), **self.arms}

    @property
    def run_threads(self) -> int:
        """The torch threads each run asks for: :attr:`default_threads` or ``base.threads``."""
        return int(self.base.get("threads", self.default_threads))

    @property
    def default_threads(self) -> int:
        """Torch and ALE threads per run unless ``base`` sets them: 2 // ``workers`` side by
        side (two single-threaded runs on 2 cores beat one two-threaded run), 2 alone."""
        return max(1, 2 // self.workers) if self.workers > 1 else 2

    def process_threads(self) -> int | None:
        """The torch threads the recipe sets in its own process: with ``workers=1`` (and the
        local launcher) the runs train in that process, so its thread count is theirs
        (``base.threads=1`` of two sweeps side by side would otherwise leave each at torch's
        default of one thread per core: 4 busy threads on 2 cores, about 10x slower);
        ``None`` when the runs have worker processes of their own."""
        return self.run_threads if self.workers == 1 and self.launcher == "local" else None

    def arm(self, name: str) -> tuple[str, dict]:
        """(the variant, the AtariConfig overrides) of a name in ``variants``."""
        if name in self.all_arms:
            spec = dict(self.all_arms[name])
            spec.pop("base", None)
            return spec.pop("variant"), spec
        return name, {}

    def bases(self) -> dict[str, tuple[str, str]]:
        """arm -> (its ``base``, the option it adds to it as ``key=value`` text), for every
        arm that names a base: the pairs :func:`option_effects` compares."""
        out = {}
        for name, spec in self.all_arms.items():
            if spec.get("base"):
                out[name] = (spec["base"], option_text(self.arm(name), self.arm(spec["base"])))
        return out

    def validate(self) -> CompareConfig:
        from torchrl_hybrid.experiments.arms import check_arms
        from torchrl_hybrid.families.atari import ATARI_VARIANTS
        from torchrl_hybrid.variants import get_variant

        check_arms(self.arms, self.all_arms, ATARI_VARIANTS, (), "plus AtariConfig overrides")
        bad = sorted(set(self.variants) - set(ATARI_VARIANTS) - set(self.all_arms))
        if bad:
            raise ValueError(
                f"unknown Atari variant(s) {bad}; choose from {list(ATARI_VARIANTS)} "
                f"or the arms {list(self.all_arms)} (or define one: '+arms.NAME={{variant: hybrid_dual, "
                "loss: {bc_labels: soft}}')"
            )
        if self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers}")
        if self.launcher not in LAUNCHERS:
            raise ValueError(f"launcher={self.launcher!r}: choose one of {LAUNCHERS}")
        for label, folder in self.baselines.items():
            if not Path(folder).is_dir():
                raise FileNotFoundError(f"baselines.{label}: {folder!r} is not a folder written by atari_compare")
        if not self.analyse_only and any(get_variant(self.arm(v)[0]).bc is not None for v in self.variants):
            missing = [g for g in self.games if not self.demos.get(g)]
            if missing:
                raise ValueError(
                    f"no demos for {missing}: record them with recipes/atari_demos.py and pass "
                    + " ".join(f"+demos.{g}=<folder>" for g in missing)
                )
            for g in self.games:
                if not (Path(self.demos[g]) / "metadata.json").exists():
                    raise FileNotFoundError(
                        f"demos for {g}: {self.demos[g]!r} holds no dataset "
                        "(metadata.json); record it with recipes/atari_demos.py"
                    )
        return self


def option_text(arm: tuple[str, dict], base: tuple[str, dict]) -> str:
    """What ``arm`` sets that ``base`` does not, as ``key=value`` pairs (both given as
    :meth:`CompareConfig.arm` returns them): e.g. ``loss.bc_confidence=0.6``. A setting
    the base has and the arm lacks reads ``key=default``."""
    (av, ao), (bv, bo) = arm, base
    a, b = flatten_dict(ao), flatten_dict(bo)
    if av != bv:
        a, b = {"variant": av, **a}, {"variant": bv, **b}
    parts = [f"{k}={v}" for k, v in a.items() if b.get(k, object()) != v]
    parts += [f"{k}=default" for k in b if k not in a]
    return ", ".join(parts) or "(same settings)"


def _run_dir(cfg: CompareConfig, game: str, variant: str, seed: int) -> Path:
    return Path(cfg.out_dir) / game / f"{variant}_s{seed}"


#: the settings on which a comparison's run must agree with the run of that name already in
#: its folder: those a checkpoint is resumed on, plus the length and the learning curve's points
STUDY_KEYS = ("total_frames", "logger.log_every_frames", "logger.accuracy_pairs", "logger.eval_episodes")


def _looks_like_compare(folder: Path) -> bool:
    """A comparison folder written before ``study.json``: ``<game>/<arm>_s<seed>`` run folders."""
    return (folder / "summary.json").exists() or any(
        p.is_dir() and p.name.rpartition("_s")[2].isdigit() and (p / "config.json").exists()
        for g in folder.iterdir()
        if g.is_dir()
        for p in g.iterdir()
    )


def _one(job: tuple[dict, str]) -> tuple[str, float]:
    """One run. Whether it resumes is decided when it starts: a run interrupted mid-way
    (or whose worker died and was restarted) goes on from its last checkpoint; one cut
    before its first checkpoint starts again (replacing its partial curve)."""
    from torchrl_hybrid.families.atari import atari_config, train_atari
    from torchrl_hybrid.utils.process import configure_worker

    d, name = job
    configure_worker(d.get("threads"))
    ckpt = not d.get("overwrite") and (Path(d["out_dir"]) / "checkpoint").exists()
    t0 = time.perf_counter()
    train_atari(atari_config(merge_dicts(d, {"resume": ckpt, "overwrite": not ckpt})))
    return name, time.perf_counter() - t0


def _logged_frames(run_dir: Path) -> int:
    """The game frames of ``run_dir``'s last logged row (0 before its first one)."""
    f = run_dir / "metrics.csv"
    try:
        with open(f, "rb") as fh:
            fh.seek(0, 2)
            start = max(0, fh.tell() - 4096)
            fh.seek(start)
            lines = fh.read().decode(errors="replace").split("\n")
    except FileNotFoundError:
        return 0
    # only whole rows: the last piece may be a row being written, the first one cut by the seek
    lines = lines[1 if start else 0 : -1]
    for line in reversed(lines):
        head = line.split(",", 1)[0]
        if head.isdigit():
            return int(head)
    return 0


class SweepProgress:
    """A progress bar over the game frames of a sweep's runs, read every ``interval``
    seconds from their ``metrics.csv`` (when several runs train side by side their own
    bars are off). Frames a resumed run had already done before the sweep started
    count as done from the start, so the rate and time left are this sweep's own."""

    def __init__(self, run_dirs: Sequence[Path], frames_per_run: int, interval: float = 30.0, disable: bool = False):
        from tqdm import tqdm

        self.run_dirs = [Path(d) for d in run_dirs]
        self.frames_per_run = int(frames_per_run)
        self.interval = interval
        start = self.frames()
        self.bar = tqdm(
            total=len(self.run_dirs) * self.frames_per_run,
            initial=start,
            unit="frame",
            unit_scale=True,
            desc=f"{len(self.run_dirs)} run(s)",
            disable=disable,
        )
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._poll, daemon=True)

    def frames(self) -> int:
        return sum(
            self.frames_per_run if (d / "summary.json").exists() else min(_logged_frames(d), self.frames_per_run)
            for d in self.run_dirs
        )

    def refresh(self) -> int:
        self.bar.n = self.frames()
        self.bar.refresh()
        return self.bar.n

    def write(self, line: str) -> None:
        self.bar.write(line)

    def _poll(self) -> None:
        while not self._stop.wait(self.interval):
            self.refresh()

    def __enter__(self) -> SweepProgress:
        if not self.bar.disable:  # a hidden bar needs no polling of the runs' files
            self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        self.refresh()
        self.bar.close()


def run_compare(cfg: CompareConfig) -> dict[str, Any]:
    """Runs the missing runs (``workers`` at a time, torch and ALE threads split
    between them), then :func:`analyse_compare`. With ``analyse_only`` it starts
    nothing: it names the runs that are not finished and analyses the others."""
    import dataclasses

    from torchrl_hybrid.families.atari import _RESUME_IGNORE, _RESUME_KEYS, AtariConfig, atari_config

    cfg.validate()
    if cfg.analyse_only:
        todo = [
            f"{g}/{n}_s{s}"
            for g in cfg.games
            for n in cfg.variants
            for s in cfg.seeds
            if not (_run_dir(cfg, g, n, s) / "summary.json").exists()
        ]
        print(
            f"analyse_only: {len(todo)} run(s) not finished, left out" + (f": {', '.join(todo)}" if todo else ""),
            flush=True,
        )
        result = analyse_compare(cfg)
        if not result:
            raise FileNotFoundError(
                f"analyse_only: no finished run of {list(cfg.games)} x {list(cfg.variants)} "
                f"x seeds {list(cfg.seeds)} in {cfg.out_dir!r} (nor in the baselines)"
            )
        return result
    threads = cfg.default_threads
    planned = []
    for game in cfg.games:
        for name in cfg.variants:
            variant, overrides = cfg.arm(name)
            for seed in cfg.seeds:
                out = _run_dir(cfg, game, name, seed)
                d = merge_dicts(
                    {
                        "threads": threads,
                        "env": {"num_threads": threads},
                        "logger": {"progress_bar": cfg.workers == 1 and cfg.launcher == "local"},
                    },
                    cfg.base,
                )
                d = merge_dicts(d, overrides)
                d = merge_dicts(
                    d,
                    {
                        "variant": variant,
                        "seed": seed,
                        "total_frames": cfg.total_frames,
                        "out_dir": str(out),
                        "env": {"game": game},
                        "demo": {"path": cfg.demos.get(game) if variant != "a2c" else None},
                    },
                )
                planned.append(planned_run(f"{game}/{name}_s{seed}", out, d, atari_config))
    with open_study(cfg.out_dir, "atari_compare", looks_like=_looks_like_compare, overwrite=cfg.overwrite) as study:
        named, changed = runs_to_do(
            planned,
            cfg.out_dir,
            _RESUME_KEYS + STUDY_KEYS,
            ignore=_RESUME_IGNORE,
            defaults=dataclasses.asdict(AtariConfig()),
            overwrite=cfg.overwrite,
        )
        jobs = [(d, n) for n, d in named]
        if jobs:
            study.record_session()
        print(
            f"{len(jobs)} run(s) to do in {cfg.out_dir}"
            + (" on Ray" if cfg.launcher == "ray" else "")
            + (f" ({len(changed)} again with the new settings)" if changed else ""),
            flush=True,
        )
        t0 = time.perf_counter()
        # one run alone shows its own bar; side by side (or on a cluster whose workers write
        # elsewhere) they don't, and this bar follows their metrics.csv here
        bar_off = not jobs or (cfg.workers == 1 and cfg.launcher == "local") or cfg.address is not None
        with SweepProgress([Path(d["out_dir"]) for d, _ in jobs], cfg.total_frames, disable=bar_off) as progress:
            # a run takes `threads` CPUs (torch + ALE threads) of a Ray node
            for name, secs in run_jobs(
                _one,
                jobs,
                launcher=cfg.launcher,
                workers=cfg.workers,
                address=cfg.address,
                cpus_per_job=threads if cfg.launcher == "ray" else 1,
                max_retries=cfg.max_retries,
                fresh_process=True,
            ):
                progress.write(f"  {name}: {secs / 60:.1f} min ({time.perf_counter() - t0:.0f} s since start)")
        return analyse_compare(cfg)


def _load_run(d: Path, seed: int) -> dict:
    with open(d / "metrics.csv") as f:
        rows = [
            upgrade_accuracy_keys({k: float(v) if v not in ("", None) else math.nan for k, v in r.items()})
            for r in csv.DictReader(f)
        ]
    summary = upgrade_accuracy_keys(read_json(d / "summary.json", "run summary"))
    config = read_json(d / "config.json", "run config") if (d / "config.json").exists() else {}
    return {"seed": seed, "rows": rows, "summary": summary, "config": config}


def grad_norm_key(columns) -> str:
    """The metrics column of a run's gradient norm before the clip: ``grad_norm`` (one global
    clip) or, for ``optim.clip=per_group``, the policy group's ``grad_norm_policy``."""
    return "grad_norm" if "grad_norm" in columns else "grad_norm_policy"


def _finished_runs(game_dir: Path) -> dict[str, list[int]]:
    """arm -> the seeds of the finished runs (``<arm>_s<seed>/summary.json``) in a game's folder."""
    found: dict[str, list[int]] = {}
    for d in sorted(game_dir.glob("*_s*")):
        name, _, seed = d.name.rpartition("_s")
        if name and seed.isdigit() and (d / "summary.json").exists():
            found.setdefault(name, []).append(int(seed))
    return {k: sorted(v) for k, v in found.items()}


def load_runs(cfg: CompareConfig, game: str) -> dict[str, list[dict]]:
    """variant -> the finished runs of ``game`` (metrics rows and summary): every finished
    run in ``<out_dir>/<game>``, ``cfg.variants`` first, then the folder's other arms (a
    sweep of some arms or seeds into a folder thus keeps the others in its tables instead
    of rewriting them with its own runs only); then the finished runs of ``cfg.baselines``
    as ``"<variant> (<label>)"``."""
    out: dict[str, list[dict]] = {}
    found = _finished_runs(Path(cfg.out_dir) / game)
    for variant in list(cfg.variants) + sorted(set(found) - set(cfg.variants)):
        for seed in found.get(variant, []):
            d = _run_dir(cfg, game, variant, seed)
            out.setdefault(f"{variant} ({cfg.label})" if cfg.label else variant, []).append(_load_run(d, seed))
    for label, folder in cfg.baselines.items():
        for variant, seeds in _finished_runs(Path(folder) / game).items():
            for seed in seeds:
                out.setdefault(f"{variant} ({label})", []).append(
                    _load_run(Path(folder) / game / f"{variant}_s{seed}", seed)
                )
    return out


def _score_curve(rows: list[dict], frames: np.ndarray, window: int) -> np.ndarray:
    """Mean episode score over the last ``window`` game frames at each of ``frames``,
    weighting each logged window by its number of finished episodes."""
    f = np.array([r["frames"] for r in rows])
    n = np.array([r.get("episodes", 0.0) for r in rows])
    s = np.nan_to_num(np.array([r.get("return_mean", math.nan) for r in rows])) * n
    out = np.full(len(frames), math.nan)
    for i, x in enumerate(frames):
        m = (f <= x) & (f > x - window)
        if n[m].sum() > 0:
            out[i] = s[m].sum() / n[m].sum()
    return out


def _ci(x: np.ndarray) -> list[float] | None:
    """Bootstrap 95 % interval of the mean over seeds, where 3 or more seeds have a value."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if not has_interval(x):
        return None
    _, lo, hi = mean_ci(x)
    return [round(lo, 2), round(hi, 2)]


def _per_seed(ax, runs: list[dict], key: str, ci: int, variant: str) -> None:
    """One thin line per seed of a logged column (rows where it is missing skipped)."""
    for k, r in enumerate(runs):
        pts = [(row["frames"], row[key]) for row in r["rows"] if not math.isnan(row.get(key, math.nan))]
        if pts:
            ax.plot(*zip(*pts), color=f"C{ci}", lw=1, label=variant if k == 0 else None)


REFERENCE = "a2c"


def _reference(rows: list[dict]) -> dict | None:
    """The row every arm is compared with: ``a2c``, or where the comparison has none of its
    own, the first ``a2c (<label>)`` of a baseline folder."""
    return next((t for t in rows if t["variant"] == REFERENCE), None) or next(
        (t for t in rows if t["variant"].startswith(f"{REFERENCE} (")), None
    )


def _auc_test(a, b, more: str, less: str, same: str) -> dict:
    """AUC per seed of an arm (``a``) and of the arm it is compared with (``b``; NaN: a seed
    without a score): the difference of the means, its bootstrap 95 % interval, a two-sided
    permutation p and a verdict, ``more`` / ``less`` where the interval excludes 0, else
    ``same``. With fewer than 3 finite seeds on either side (a percentile bootstrap of 2
    values is no interval) the numbers are None and the verdict says so."""
    a, b = np.array(a, float), np.array(b, float)
    a, b = a[np.isfinite(a)], b[np.isfinite(b)]
    if not has_interval(a, b):
        return {
            "diff": None,
            "ci95": None,
            "p": None,
            "verdict": f"too few seeds ({len(a)} vs {len(b)} finished with a score; 3 each needed)",
        }
    d, lo, hi = mean_diff_ci(a, b)
    return {
        "diff": round(d, 2),
        "ci95": [round(lo, 2), round(hi, 2)],
        "p": round(permutation_p(a, b), 3),
        "verdict": more if lo > 0 else less if hi < 0 else same,
    }


def _versus_reference(table: list[dict]) -> None:
    """Adds to each row the difference of its mean AUC to ``a2c``'s (:func:`_reference`), its bootstrap 95 %
    interval and a two-sided permutation-test p-value (both need 3 or more finite seeds
    on each side: a percentile bootstrap of 2 values is no interval), and a verdict:
    ``faster`` / ``slower`` where the interval excludes 0, else ``not distinguishable``. With 3 seeds against 3 the smallest
    attainable p is 0.1 (all 20 splits enumerated), so p says how far from that the
    seeds are; the interval is the criterion."""
    ref = _reference(table)
    for t in table:
        t.update({"auc_minus_a2c": None, "auc_minus_a2c_ci95": None, "auc_vs_a2c_p": None, "verdict_vs_a2c": ""})
        if ref is None or t is ref:
            continue
        test = _auc_test(t["auc_per_seed"], ref["auc_per_seed"], "faster", "slower", "not distinguishable")
        t.update(
            {
                "auc_minus_a2c": test["diff"],
                "auc_minus_a2c_ci95": test["ci95"],
                "auc_vs_a2c_p": test["p"],
                "verdict_vs_a2c": test["verdict"],
            }
        )


def _split_label(name: str) -> tuple[str, str]:
    """``"hybrid_dual_gate (soft demos)"`` -> ``("hybrid_dual_gate", " (soft demos)")``."""
    arm, sep, label = name.partition(" (")
    return arm, f"{sep}{label}"


def option_effects(table: list[dict], bases: dict[str, tuple[str, str]]) -> None:
    """The measured effect of each robust option: adds to each row whose arm names a base
    (``bases``: arm -> (base, option text), :meth:`CompareConfig.bases`) and whose base is
    in the table with the same label, the option (``option``), the base (``option_base``),
    the difference of the mean AUCs, arm minus base, with its bootstrap 95 % interval and
    permutation p (3 or more seeds each), and ``option_effect``: ``raises the AUC`` /
    ``lowers the AUC`` where the interval excludes 0, else ``no measurable effect``, or
    why there is no verdict. Rows without a base get empty fields."""
    by_name = {t["variant"]: t for t in table}
    for t in table:
        t.update(
            {
                "option": "",
                "option_base": "",
                "auc_minus_base": None,
                "auc_minus_base_ci95": None,
                "auc_vs_base_p": None,
                "option_effect": "",
            }
        )
        arm, label = _split_label(t["variant"])
        if arm not in bases:
            continue
        base_arm, option = bases[arm]
        base = by_name.get(f"{base_arm}{label}")
        t.update({"option": option, "option_base": f"{base_arm}{label}"})
        if base is None:
            t["option_effect"] = f"no finished {base_arm}{label} run here to compare with"
            continue
        test = _auc_test(
            t["auc_per_seed"], base["auc_per_seed"], "raises the AUC", "lowers the AUC", "no measurable effect"
        )
        t.update(
            {
                "auc_minus_base": test["diff"],
                "auc_minus_base_ci95": test["ci95"],
                "auc_vs_base_p": test["p"],
                "option_effect": test["verdict"],
            }
        )


def _summary_markdown(
    game: str, table: list[dict], window: int, milestones: dict[str, tuple[list[int], list[float]]] | None = None
) -> str:
    """The per-game table of ``summary.csv`` as Markdown, to paste into a README, and
    with ``milestones`` (variant -> frames, mean score over seeds there) a second table
    of the score along the run."""

    def num(x) -> str:
        return "–" if x is None or not math.isfinite(x) else f"{x:.2f}"

    def ci(c) -> str:
        return f" [{c[0]:.2f}, {c[1]:.2f}]" if c else ""

    def seeds(xs) -> str:
        return ", ".join(num(x) for x in xs)

    lines = [
        f"### {game}",
        "",
        f"Score: mean raw episode score over the last {window / 1000:g}k game frames; final = at the end, "
        "AUC = mean of that curve over the run (higher = learned faster). Intervals: bootstrap 95 % over "
        "seeds (3 or more); AUC − a2c: difference of means, its bootstrap interval and a permutation-test p "
        "(3 seeds against 3: p ≥ 0.1).",
        "",
        "| variant | seeds | final per seed | final mean | AUC per seed | AUC mean | IDM accuracy | "
        "AUC − a2c | faster than a2c? |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for t in table:
        acc = t[IDM_ACCURACY_EXPERT]
        diff = (
            "–"
            if t["auc_minus_a2c"] is None
            else f"{t['auc_minus_a2c']:+.2f} [{t['auc_minus_a2c_ci95'][0]:+.2f}, {t['auc_minus_a2c_ci95'][1]:+.2f}],"
            f" p = {t['auc_vs_a2c_p']:.2f}"
        )
        lines.append(
            f"| {t['variant']} | {t['seeds']} | {seeds(t['final_per_seed'])} | "
            f"{num(t['final_mean'])}{ci(t['final_ci95'])} | {seeds(t['auc_per_seed'])} | "
            f"{num(t['auc_mean'])}{ci(t['auc_ci95'])} | {'–' if acc is None else f'{acc:.1%}'} | {diff} | "
            f"{t['verdict_vs_a2c'] or '–'} |"
        )
    effects = [t for t in table if t.get("option")]
    if effects:
        lines += [
            "",
            "Effect of each option: the arm's AUC minus that of the arm without the option (its base), "
            "the difference's bootstrap 95 % interval and a permutation-test p:",
            "",
            "| arm | option | without it (base) | AUC − base | effect |",
            "|---|---|---|---|---|",
        ]
        for t in effects:
            diff = (
                "–"
                if t["auc_minus_base"] is None
                else f"{t['auc_minus_base']:+.2f} [{t['auc_minus_base_ci95'][0]:+.2f}, "
                f"{t['auc_minus_base_ci95'][1]:+.2f}], p = {t['auc_vs_base_p']:.2f}"
            )
            lines.append(f"| {t['variant']} | `{t['option']}` | {t['option_base']} | {diff} | {t['option_effect']} |")
    if milestones:
        frames = next(iter(milestones.values()))[0]
        lines += [
            "",
            f"Mean score over seeds (last {window / 1000:g}k frames) along the run:",
            "",
            "| variant | " + " | ".join(f"{x / 1e6:g}M" for x in frames) + " |",
            "|---|" + "---|" * len(frames),
        ]
        lines += [f"| {v} | " + " | ".join(num(x) for x in scores) + " |" for v, (_, scores) in milestones.items()]
    return "\n".join(lines) + "\n"


def analyse_compare(cfg: CompareConfig, window: int = 200_000) -> dict[str, Any]:
    """Per game, over every finished run in ``<out_dir>/<game>`` (:func:`load_runs`) and the
    baselines: ``curves.csv`` (every logged point of every run), ``summary.csv``
    (with each variant's AUC against ``a2c``, :func:`_versus_reference`, and each robust
    option's effect, the arm's AUC against its base arm's, :func:`option_effects`), the same
    table as ``summary.md``, and ``comparison.png`` (mean score over the last ``window`` frames, seeds thin;
    the inverse model's accuracy on demo pairs; the policy's entropy; the gradient norm of each
    update before the clip, whose dashed line is ``optim.max_grad_norm``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    result: dict[str, Any] = {}
    root = Path(cfg.out_dir)
    for game in cfg.games:
        runs = load_runs(cfg, game)
        if not runs:
            continue
        gdir = root / game
        with open(gdir / "curves.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(
                [
                    "variant",
                    "seed",
                    "frames",
                    "episodes",
                    "return_mean",
                    IDM_ACCURACY_EXPERT,
                    IDM_ACCURACY_AGENT,
                    "entropy",
                    "loss_bc",
                    "grad_norm",
                ]
            )
            for variant, rs in runs.items():
                for r in rs:
                    for row in r["rows"]:
                        w.writerow(
                            [
                                variant,
                                r["seed"],
                                int(row["frames"]),
                                int(row.get("episodes", 0)),
                                row.get("return_mean", math.nan),
                                row.get(IDM_ACCURACY_EXPERT, ""),
                                row.get(IDM_ACCURACY_AGENT, ""),
                                row.get("entropy", ""),
                                row.get("loss_bc", ""),
                                row.get(grad_norm_key(row), ""),
                            ]
                        )
        # the logged frames of the longest run; the window shrinks for short runs
        longest = max((r["rows"] for rs in runs.values() for r in rs), key=len)
        grid = np.array([row["frames"] for row in longest])
        win = min(window, int(grid[-1]))
        grid = grid[grid >= win]
        fig, axes = plt.subplots(1, 4, figsize=(22, 4.2))
        table = []
        # five points along the run (every 1M frames of a 5M run)
        marks = [int(grid[-1] * k / 5) for k in range(1, 6)]
        milestones = {}
        for ci, (variant, rs) in enumerate(runs.items()):
            curves = np.array([_score_curve(r["rows"], grid, win) for r in rs])
            for c in curves:
                axes[0].plot(grid, c, color=f"C{ci}", lw=0.8, alpha=0.4)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                mean_curve = np.nanmean(curves, 0)
            axes[0].plot(grid, mean_curve, color=f"C{ci}", lw=2, label=f"{variant} ({len(rs)} seeds)")
            final = curves[:, -1]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                milestones[variant] = (
                    marks,
                    np.nanmean([_score_curve(r["rows"], np.array(marks), win) for r in rs], 0).tolist(),
                )
            with warnings.catch_warnings():  # NaN where no episode has finished yet
                warnings.simplefilter("ignore", RuntimeWarning)
                auc = np.nanmean(curves, 1)  # mean of the smoothed curve = normalised area under it
                final_mean, auc_mean = float(np.nanmean(final)), float(np.nanmean(auc))
            acc = [r["summary"].get(IDM_ACCURACY_EXPERT) for r in rs]
            table.append(
                {
                    "variant": variant,
                    "seeds": len(rs),
                    "final_mean": final_mean,
                    "final_ci95": _ci(final),
                    "final_per_seed": [round(float(x), 2) for x in final],
                    "auc_mean": auc_mean,
                    "auc_ci95": _ci(auc),
                    "auc_per_seed": [round(float(x), 2) for x in auc],
                    IDM_ACCURACY_EXPERT: None if acc[0] is None else float(np.mean(acc)),
                    "frames_per_s": float(np.mean([r["summary"]["frames_per_s"] for r in rs])),
                }
            )
            _per_seed(axes[1], rs, IDM_ACCURACY_EXPERT, ci, variant)
            _per_seed(axes[2], rs, "entropy", ci, variant)
            for k, r in enumerate(rs):  # one column or the other, per run
                _per_seed(
                    axes[3], [r], grad_norm_key(r["rows"][0] if r["rows"] else {}), ci, variant if k == 0 else None
                )
        axes[1].set_ylim(0, 1)
        clips = {r["config"].get("optim", {}).get("max_grad_norm") for rs in runs.values() for r in rs} - {None}
        for c in clips:  # the gradient is scaled down to this norm before each step (optim.max_grad_norm)
            axes[3].axhline(c, color="k", ls="--", lw=1, label=f"clip {c:g}")
        if any(ax_line.get_ydata().size for ax_line in axes[3].get_lines()):
            axes[3].set_yscale("log")
        for ax, ylabel, title, loc in (
            (
                axes[0],
                f"episode score (raw), mean over last {win // 1000}k frames",
                f"{game}: hybrid vs A2C",
                "upper left",
            ),
            (axes[1], "inferred = true expert action", "inverse-model accuracy on demo pairs", "lower right"),
            (
                axes[2],
                "policy entropy (nats) on the agent's batch",
                "policy entropy (BC collapse shows as ~0)",
                "center right",
            ),
            (
                axes[3],
                "gradient norm before the clip (per-group clip: the policy's)",
                "gradient norm of each update",
                "upper left",
            ),
        ):
            ax.set(xlabel="game frames", ylabel=ylabel, title=title)
            ax.grid(alpha=0.3)
            if ax.get_legend_handles_labels()[0]:
                ax.legend(loc=loc)
        fig.tight_layout()
        fig.savefig(gdir / "comparison.png", dpi=110)
        plt.close(fig)
        _versus_reference(table)
        option_effects(table, cfg.bases())
        with open(gdir / "summary.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(table[0]))
            w.writeheader()
            w.writerows(table)
        made = study_provenance(gdir.parent)
        (gdir / "summary.md").write_text(
            _summary_markdown(game, table, win, milestones) + (f"\n{made}\n" if made else "")
        )
        result[game] = table

        def ci_txt(c):
            return f" [{c[0]:.2f}, {c[1]:.2f}]" if c else ""

        for t in table:
            print(
                f"{game:10s} {t['variant']:12s} seeds {t['seeds']}  final {t['final_mean']:7.2f}{ci_txt(t['final_ci95'])} "
                f"{t['final_per_seed']}  AUC {t['auc_mean']:7.2f}{ci_txt(t['auc_ci95'])} {t['auc_per_seed']}"
                + (f"  IDM acc {t[IDM_ACCURACY_EXPERT]:.1%}" if t[IDM_ACCURACY_EXPERT] is not None else "")
                + (
                    f"  AUC - a2c {t['auc_minus_a2c']:+.2f}{ci_txt(t['auc_minus_a2c_ci95'])} p {t['auc_vs_a2c_p']:.2f}"
                    f" ({t['verdict_vs_a2c']})"
                    if t["auc_minus_a2c"] is not None
                    else ""
                )
                + (
                    f"  [{t['option']}: AUC - {t['option_base']} {t['auc_minus_base']:+.2f}"
                    f"{ci_txt(t['auc_minus_base_ci95'])} p {t['auc_vs_base_p']:.2f} ({t['option_effect']})]"
                    if t.get("auc_minus_base") is not None
                    else ""
                )
            )
    # one file for the whole out_dir: a comparison of other games (or a later one of some
    # games) updates their entries and keeps the rest
    path = root / "summary.json"
    try:
        kept = read_json(path, "comparison summary") if path.exists() else {}
    except json.JSONDecodeError:  # derived data: rewritten from the runs' own files
        warnings.warn(
            f"{path} is not valid JSON (truncated?); rewriting it with this comparison's games only", stacklevel=2
        )
        kept = {}
    merged = {**kept, **result}
    path.write_text(json.dumps(merged, indent=2))
    if result:
        overview_figure(merged, root / "overview.png")
        if any(t.get("auc_minus_base") is not None for rows in merged.values() if _is_table(rows) for t in rows):
            effects_figure(merged, root / "effects.png")
    return result


def _is_table(rows: Any) -> bool:
    return (
        isinstance(rows, list)
        and bool(rows)
        and all(isinstance(t, dict) and {"variant", "auc_per_seed", "final_per_seed"} <= set(t) for t in rows)
    )


def overview_figure(summary: dict[str, list[dict]], path: str | Path) -> dict[str, list[str]]:
    """Every game of a comparison folder in one figure, from its ``summary.json``
    (``{game: [row of summary.csv, ...]}``): a row of panels per game, AUC (mean score
    over the run: higher = learned faster) on the left and final score on the right;
    per arm, each seed as a dot and, with 3 or more seeds, the mean with its bootstrap 95 %
    interval; ``a2c``'s mean and interval as a line and band, and each arm's verdict
    against it (:func:`_versus_reference`) beside the AUC. A game whose entry is not
    such a table (an older format, a hand edit) is left out with a warning. Returns
    game -> the arms drawn, in drawing order (top to bottom)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    games = []
    for game, rows in summary.items():
        if _is_table(rows):
            games.append(game)
        else:
            warnings.warn(
                f"overview: {game!r} in summary.json is not a comparison table; left out of the figure "
                "(rerun recipes/atari_compare.py analyse_only=true for it to rewrite the entry)",
                stacklevel=2,
            )
    if not games:
        raise ValueError("overview: summary holds no comparison table (run recipes/atari_compare.py first)")
    heights = [1 + len(summary[g]) for g in games]
    fig, axes = plt.subplots(
        len(games),
        2,
        figsize=(15, 0.55 * sum(heights) + 0.6 * len(games)),
        gridspec_kw={"height_ratios": heights},
        squeeze=False,
    )
    # one colour per arm across games (a2c first)
    names = list(dict.fromkeys([REFERENCE] + [t["variant"] for g in games for t in summary[g]]))
    colour = {n: f"C{i % 10}" for i, n in enumerate(names)}
    drawn: dict[str, list[str]] = {}
    for (ax_auc, ax_final), game in zip(axes, games):
        rows = summary[game]
        ref = _reference(rows)
        order = ([ref] if ref else []) + [t for t in rows if t is not ref]
        drawn[game] = [t["variant"] for t in order]
        y = np.arange(len(order))[::-1]  # the first arm (a2c) on top
        for ax, key in ((ax_auc, "auc"), (ax_final, "final")):
            if ref is not None:
                ax.axvline(ref[f"{key}_mean"], color=colour[ref["variant"]], lw=1.5, zorder=1)
                if ref.get(f"{key}_ci95"):
                    ax.axvspan(*ref[f"{key}_ci95"], color=colour[ref["variant"]], alpha=0.15, lw=0, zorder=0)
            for yi, t in zip(y, order):
                c = colour[t["variant"]]
                seeds = np.array([x if x is not None else math.nan for x in t[f"{key}_per_seed"]], float)
                ax.plot(seeds, np.full(len(seeds), yi), "o", color=c, ms=5, alpha=0.6, mfc="none")
                interval = t.get(f"{key}_ci95")
                if interval:
                    m = t[f"{key}_mean"]
                    ax.errorbar(
                        [m], [yi], xerr=[[m - interval[0]], [interval[1] - m]], fmt="D", color=c, ms=7, capsize=4, lw=2
                    )
                elif np.isfinite(seeds).any():
                    ax.plot([np.nanmean(seeds)], [yi], "D", color=c, ms=7, mfc="white")
            ax.set_yticks(y, [f"{t['variant']} ({t.get('seeds', len(t[f'{key}_per_seed']))})" for t in order])
            ax.set_ylim(-0.7, len(order) - 0.3)
            ax.grid(axis="x", alpha=0.3)
        for yi, t in zip(y, order):
            if t is not ref and t.get("verdict_vs_a2c"):
                verdict = t["verdict_vs_a2c"]
                text = verdict if verdict in ("faster", "slower", "not distinguishable") else "< 3 seeds"
                if t.get("auc_vs_a2c_p") is not None:
                    text += f" (p = {t['auc_vs_a2c_p']:.2f})"
                ax_auc.annotate(
                    text,
                    (1.0, yi),
                    xycoords=("axes fraction", "data"),
                    xytext=(4, 0),
                    textcoords="offset points",
                    va="center",
                    fontsize=8,
                    color={"faster": "green", "slower": "firebrick"}.get(verdict, "0.35"),
                )
        ax_auc.set_title(f"{game}: AUC (mean score over the run; higher = learned faster)", fontsize=10)
        ax_final.set_title(f"{game}: final score (end of the run)", fontsize=10)
    fig.text(
        0.01,
        0.003,
        "Raw episode score, mean over the analysis window (200k game frames by default). Dots: seeds; diamond: mean "
        "(filled, with its bootstrap 95 % interval, where 3 or more seeds); line and band: a2c's mean and "
        "interval.\nBeside the AUC: the arm's verdict against a2c (interval of the AUC difference, "
        "permutation p). (n) = seeds.",
        fontsize=8,
        va="bottom",
    )
    fig.tight_layout(rect=(0, 0.035, 1, 1), w_pad=9)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return drawn


def effects_figure(summary: dict[str, list[dict]], path: str | Path) -> dict[str, list[str]]:
    """The measured effect of each robust option (:func:`option_effects`) on every game of a
    comparison folder, from its ``summary.json``: a panel per game (each in its own score
    units), a row per arm whose effect has an interval: the arm's AUC minus its base's, the
    bootstrap 95 % interval, the permutation p and the option, and a line at 0 (no effect).
    Returns game -> the arms drawn, top to bottom; raises ``ValueError`` where no game has
    one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = {g: [t for t in ts if t.get("auc_minus_base") is not None] for g, ts in summary.items() if _is_table(ts)}
    rows = {g: ts for g, ts in rows.items() if ts}
    if not rows:
        raise ValueError("effects: no arm in summary has a measured option effect (3 seeds of it and of its base)")
    fig, axes = plt.subplots(
        len(rows),
        1,
        figsize=(11, sum(0.9 + 0.5 * len(ts) for ts in rows.values()) + 0.6),
        gridspec_kw={"height_ratios": [1 + len(ts) for ts in rows.values()]},
        squeeze=False,
    )
    colour = {"raises the AUC": "green", "lowers the AUC": "firebrick"}
    drawn = {}
    for ax, (game, ts) in zip(axes[:, 0], rows.items()):
        y = np.arange(len(ts))[::-1]
        for yi, t in zip(y, ts):
            d, (lo, hi) = t["auc_minus_base"], t["auc_minus_base_ci95"]
            c = colour.get(t["option_effect"], "0.35")
            ax.errorbar([d], [yi], xerr=[[d - lo], [hi - d]], fmt="D", color=c, ms=7, capsize=4, lw=2)
            ax.annotate(
                f"{t['option_effect']} (p = {t['auc_vs_base_p']:.2f})",
                (1.0, yi),
                xycoords=("axes fraction", "data"),
                xytext=(4, 0),
                textcoords="offset points",
                va="center",
                fontsize=8,
                color=c,
            )
        ax.axvline(0, color="k", lw=1)
        ax.set_yticks(y, [f"{t['variant']} vs {t['option_base']}\n{t['option']}" for t in ts], fontsize=8)
        ax.set_ylim(-0.7, len(ts) - 0.3)
        ax.grid(axis="x", alpha=0.3)
        ax.set_title(f"{game}: AUC of the arm minus AUC of the arm without its option (score units)", fontsize=10)
        drawn[game] = [t["variant"] for t in ts]
    fig.text(
        0.01,
        0.003,
        "Diamond: difference of the mean AUCs over seeds, with its bootstrap 95 % interval; "
        "an effect is stated where the interval excludes 0 (3 seeds each; p >= 0.1 with 3 against 3).",
        fontsize=8,
        va="bottom",
    )
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.subplots_adjust(right=0.78)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return drawn
