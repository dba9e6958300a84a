"""The committed studies still come out of today's code: each slice reruns the start of one committed run
and compares it with the study's own files (torchrl_hybrid/experiments/reproduce.py). Exactly on the machine
kind that verified them (results/reproduce.json), within a stated tolerance elsewhere."""

import pytest

from torchrl_hybrid.experiments.reproduce import REL_TOL, SLICES, exact_here, run_slice, slice_name


@pytest.mark.parametrize("s", SLICES, ids=[slice_name(s) for s in SLICES])
def test_committed_study_reproduces(s):
    exact = exact_here(s)
    diffs = run_slice(s, exact=exact)
    how = "exactly" if exact else f"within rel. {REL_TOL} (first logged row's losses)"
    assert not diffs, (
        f"{slice_name(s)} no longer reproduces {how}; if the change is meant to move the numbers, rerun the "
        "study with its README's command, commit it in the same change, and record the machine with "
        "`python -m torchrl_hybrid.experiments.reproduce --write`:\n" + "\n".join(diffs[:10])
    )


def test_a_change_that_moves_the_numbers_is_caught(monkeypatch):
    from torchrl_hybrid.experiments import reproduce

    def with_other_entropy_bonus(a, b):  # the slice's run, with another entropy weight
        return merge(merge(a, b), {"loss": {"entropy_coeff": 0.02}})

    merge = reproduce.merge_dicts
    monkeypatch.setattr(reproduce, "merge_dicts", with_other_entropy_bonus)
    s = reproduce.Slice("results/cartpole/compare", "hybrid_dual_s0", 5_200, "gym_run")
    diffs = run_slice(s, exact=True)
    assert any("row 1" in d for d in diffs)  # row 0 is the first update's losses, before the step
