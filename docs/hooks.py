"""mkdocs hook: mounts the repository's tracked files (code, configs, results, notebooks) at their
repository paths, so that the pages' links such as ``torchrl_hybrid/variants.py`` or
``results/cartpole/compare/README.md`` resolve in the site as they do on the repository's web view.
The experts' weights come along (the only tracked ``model.pt`` files, 3.5 MB at most), so a
page's link to one downloads it."""

from __future__ import annotations

import subprocess
from pathlib import Path

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[1]
SKIP_PREFIXES = ("docs/",)
SKIP_NAMES = ("README.md", "mkdocs.yml")  # the top README is the repository's page, docs/index.md the site's


def _tracked() -> list[str]:
    """The repository's files: tracked ones and new ones not ignored (a page may link to a file
    that is not committed yet)."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        return [p for p in out.split("\0") if p]
    except (OSError, subprocess.CalledProcessError):  # not a git checkout: every file under the mounted folders
        folders = ("torchrl_hybrid", "recipes", "benchmarks", "results", "notebooks", "tests")
        return [str(p.relative_to(ROOT)) for f in folders for p in (ROOT / f).rglob("*") if p.is_file()]


@event_priority(100)  # before mkdocs-jupyter, which turns the mounted notebooks into pages
def on_files(files: Files, config) -> Files:
    for path in _tracked():
        if path.startswith(SKIP_PREFIXES) or path in SKIP_NAMES:
            continue
        if not (ROOT / path).is_file() or files.get_file_from_path(path) is not None:
            continue
        files.append(
            File(path, src_dir=str(ROOT), dest_dir=config["site_dir"], use_directory_urls=config["use_directory_urls"])
        )
    return files
