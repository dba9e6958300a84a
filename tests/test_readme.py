"""The README's code examples run as written (with fewer frames)."""

import re
from pathlib import Path

import torch

README = Path(__file__).resolve().parents[1] / "README.md"


def _readme_block(marker: str = "<!-- tested: tests/test_readme.py runs this block -->") -> str:
    text = README.read_text()
    assert marker in text, f"README.md lost the block marked {marker}"
    block = re.search(r"```python\n(.*?)```", text[text.index(marker) :], re.S)
    return block.group(1)


def test_readme_ppo_in_a_torchrl_trainer_with_the_hybrid_losses():
    code = _readme_block()
    assert "total_frames = 200_000" in code
    code = code.replace("total_frames = 200_000", "total_frames = 4_096")
    torch.manual_seed(0)
    scope: dict = {}
    exec(compile(code, str(README), "exec"), scope)
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
