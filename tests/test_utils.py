import math
from pathlib import Path

import numpy as np
import pytest
import torch

from torchrl_hybrid.utils.metrics import upgrade_accuracy_keys
from torchrl_hybrid.utils.stats import mean_ci, mean_diff_ci, permutation_p

ROOT = Path(__file__).resolve().parents[1]


def test_permutation_p_is_the_exact_two_sided_value_on_small_samples():
    # 20 ways to split 6 values 3/3; only the observed split and its mirror are as extreme
    assert permutation_p([1, 2, 3], [4, 5, 6]) == pytest.approx(2 / 20)
    assert permutation_p([1, 2, 3], [1, 2, 3]) == pytest.approx(1.0)


def test_bootstrap_intervals_hold_the_estimate_and_shrink_with_more_seeds():
    rng = np.random.default_rng(0)
    a, b = rng.normal(1.0, 1.0, 8), rng.normal(0.0, 1.0, 8)
    d, lo, hi = mean_diff_ci(a, b)
    assert d == pytest.approx(a.mean() - b.mean()) and lo < d < hi
    a2, b2 = rng.normal(1.0, 1.0, 128), rng.normal(0.0, 1.0, 128)
    _, lo2, hi2 = mean_diff_ci(a2, b2)
    assert hi2 - lo2 < hi - lo and lo2 > 0  # a true difference of 1 is found with 128 seeds
    m, lo, hi = mean_ci([1.0, 2.0, 3.0])
    assert m == 2.0 and 1.0 <= lo < 2.0 < hi <= 3.0
    # one minimum-seed rule for every study: no interval from 2 seeds
    with pytest.raises(ValueError, match="at least 3"):
        mean_ci([1.0, 2.0])
    with pytest.raises(ValueError, match="at least 3"):
        mean_diff_ci([1.0, 2.0, 3.0], [1.0, 2.0])


def test_legacy_files_are_read_with_the_accuracy_columns_named_apart():
    assert upgrade_accuracy_keys({"idm_accuracy": 0.8}) == {"idm_accuracy_expert": 0.8}
    new = {"idm_accuracy": 0.5, "idm_accuracy_expert": math.nan}
    assert upgrade_accuracy_keys(dict(new)).keys() == new.keys()
    from torchrl_hybrid.experiments.taxi_sweep import load_sweep

    runs, meta = load_sweep(ROOT / "results" / "taxi")  # committed before the rename
    r = runs["hybrid_dual"][0]
    assert "idm_accuracy" not in r and 0.5 < r["idm_accuracy_expert"] <= 1
    assert all("idm_accuracy_expert" in row for row in r["curve"])


def test_metrics_hook_refuses_an_evaluator_column_that_is_a_loss_output(tmp_path):
    from torchrl_hybrid.trainers.hooks import MetricsHook

    hook = MetricsHook(tmp_path / "m.csv", 10, evaluator=lambda: {"idm_accuracy": 1.0})
    hook._losses = {"idm_accuracy": torch.tensor(0.5)}
    with pytest.raises(ValueError, match="also loss outputs"):
        hook.row()
