"""What the repository itself holds: only experts' weights, nothing .gitignore excludes, no large file.

The same rules run as pre-commit hooks (.pre-commit-config.yaml); this test makes CI hold them too."""

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_BYTES = 4_000 * 1024  # check-added-large-files --maxkb=4000 in .pre-commit-config.yaml
EXPERT_WEIGHTS = re.compile(r"(^|/)expert[^/]*/model\.pt$")


def _git(*args: str) -> list[str]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    out = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    return [line for line in out.split("\0") if line]


def test_only_expert_weights_are_tracked():
    weights = [p for p in _git("ls-files", "-z") if p.endswith(".pt")]
    assert weights, "the experts' model.pt files (they rebuild the demos) should be tracked"
    others = [p for p in weights if not EXPERT_WEIGHTS.search(p)]
    assert not others, f"only experts' model.pt files belong in git; untrack: {others}"


def test_nothing_gitignore_excludes_is_tracked():
    ignored = _git("ls-files", "-z", "--cached", "--ignored", "--exclude-standard")
    assert not ignored, f"tracked but matched by .gitignore (git rm --cached them): {ignored[:10]}"


def test_no_large_file_is_tracked():
    large = [p for p in _git("ls-files", "-z") if (ROOT / p).is_file() and (ROOT / p).stat().st_size > MAX_BYTES]
    assert not large, f"files over {MAX_BYTES // 1024} KiB: {large}"
