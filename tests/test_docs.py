"""The docs hold: the own-trainer example runs as written (with fewer frames), the README stays a
short front page with its two-command quick start, and every relative link in the README and the
docs pages points at a file that exists."""

import re
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
OWN_TRAINER = ROOT / "docs" / "own-trainer.md"


def _readme_block(marker: str = "<!-- tested: tests/test_readme.py runs this block -->") -> str:
    text = OWN_TRAINER.read_text()
    assert marker in text, f"{OWN_TRAINER} lost the block marked {marker}"
    block = re.search(r"```python\n(.*?)```", text[text.index(marker) :], re.S)
    return block.group(1)


def test_readme_ppo_in_a_torchrl_trainer_with_the_hybrid_losses():
    code = _readme_block()
    assert "total_frames = 200_000" in code
    code = code.replace("total_frames = 200_000", "total_frames = 4_096")
    torch.manual_seed(0)
    scope: dict = {}
    exec(compile(code, str(OWN_TRAINER), "exec"), scope)
    trainer, optimizer, idm, actor, critic = (scope[k] for k in ("trainer", "optimizer", "idm", "actor", "critic"))
    assert trainer.collected_frames >= 4_096
    # the optimiser holds every parameter of the actor, critic and inverse model exactly once
    ids = [id(p) for g in optimizer.param_groups for p in g["params"]]
    want = {id(p) for m in (actor, critic, idm) for p in m.parameters()}
    assert len(ids) == len(set(ids)) and set(ids) == want
    assert [g["name"] for g in optimizer.param_groups] == ["policy", "inverse_model"]
    # the inverse model learned from the agent's own transitions (chance: 1/6)
    from torchrl_hybrid.trainers import inverse_model_accuracy

    assert inverse_model_accuracy(idm, scope["demos"]) > 0.4


def test_readme_is_a_short_front_page_with_the_two_command_quick_start():
    text = README.read_text()
    assert len(text.splitlines()) <= 200, "the README is the front page: move details into docs/"
    quick = re.search(r"## Quick start\n\n```bash\n(.*?)```", text, re.S)
    assert quick, "the README lost its quick start block"
    commands = [line.split("#")[0].strip() for line in quick.group(1).splitlines() if line.strip()]
    assert commands == ["make run", "make test"]


def test_every_relative_link_in_the_readme_and_the_docs_exists():
    pages = [README, *sorted((ROOT / "docs").glob("*.md"))]
    broken = []
    for page in pages:
        # docs pages link as the README does: relative to the repository root (docs/hooks.py mounts it)
        base = ROOT if page.parent.name == "docs" or page == README else page.parent
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text()):
            if "://" in target or target.startswith("mailto:"):
                continue
            here = (page.parent / target) if page == README else None
            if not (
                (base / target).exists() or (here is not None and here.exists()) or (page.parent / target).exists()
            ):
                broken.append(f"{page.relative_to(ROOT)}: {target}")
    assert not broken, "links to files that do not exist:\n" + "\n".join(broken)
