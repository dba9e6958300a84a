"""Statistics over seeds, with SciPy's resampling tests."""

from __future__ import annotations

import numpy as np
from scipy import stats

__all__ = ["MIN_SEEDS", "has_interval", "mean_ci", "mean_diff_ci", "permutation_p"]

#: the one minimum-seed rule of every study: a percentile bootstrap of 2 values is no interval
MIN_SEEDS = 3


def has_interval(*samples) -> bool:
    """Whether every sample has the :data:`MIN_SEEDS` values an interval (or a difference's
    interval, or a permutation p) needs."""
    return all(len(s) >= MIN_SEEDS for s in samples)


def _mean_diff(a, b, axis=-1):
    return np.mean(a, axis=axis) - np.mean(b, axis=axis)


def mean_diff_ci(
    a, b, *, confidence: float = 0.95, n_resamples: int = 4000, seed: int = 0
) -> tuple[float, float, float]:
    """``mean(a) - mean(b)`` for independent samples (e.g. two agents' seeds) and its
    bootstrap percentile interval (``scipy.stats.bootstrap``, each sample resampled
    on its own)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if not has_interval(a, b):
        raise ValueError(
            f"a bootstrap interval needs at least {MIN_SEEDS} values in each sample, got {len(a)} and {len(b)}"
        )
    res = stats.bootstrap(
        (a, b),
        _mean_diff,
        paired=False,
        vectorized=True,
        confidence_level=confidence,
        n_resamples=n_resamples,
        method="percentile",
        rng=np.random.default_rng(seed),
    )
    return float(_mean_diff(a, b)), float(res.confidence_interval.low), float(res.confidence_interval.high)


def mean_ci(x, *, confidence: float = 0.95, n_resamples: int = 4000, seed: int = 0) -> tuple[float, float, float]:
    """The mean of ``x`` and its bootstrap percentile interval (``scipy.stats.bootstrap``)."""
    x = np.asarray(x, float)
    if not has_interval(x):
        raise ValueError(f"a bootstrap interval needs at least {MIN_SEEDS} values, got {len(x)}")
    res = stats.bootstrap(
        (x,),
        np.mean,
        vectorized=True,
        confidence_level=confidence,
        n_resamples=n_resamples,
        method="percentile",
        rng=np.random.default_rng(seed),
    )
    return float(x.mean()), float(res.confidence_interval.low), float(res.confidence_interval.high)


def permutation_p(a, b, *, n_resamples: int = 20000, seed: int = 0) -> float:
    """Two-sided permutation-test p-value for ``mean(a) == mean(b)``
    (``scipy.stats.permutation_test``; exact when the sample is small enough)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    res = stats.permutation_test(
        (a, b),
        _mean_diff,
        permutation_type="independent",
        vectorized=True,
        n_resamples=n_resamples,
        alternative="two-sided",
        rng=np.random.default_rng(seed),
    )
    return float(res.pvalue)
