"""Expert checkpoints: the actor of a ``model.pt`` written by an earlier run, rebuilt
from the settings stored beside its weights (Atari: :func:`load_expert`; vector-observation
gymnasium envs: :func:`load_gym_expert`)."""

from __future__ import annotations

from pathlib import Path

import torch

from torchrl_hybrid.modules import make_atari_actor_critic, make_mlp_actor_critic
from torchrl_hybrid.utils.device import resolve_device

__all__ = ["load_expert", "load_gym_expert"]


def load_expert(path: str | Path, device: str | torch.device = "cpu"):
    """The actor of a checkpoint written by :func:`train_atari` (``model.pt``), on
    ``device`` whatever device it was saved from, and the checkpoint's metadata."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(
            f"expert checkpoint {str(path)!r} does not exist; train one with recipes/atari_expert.py"
        )
    device = resolve_device(device)
    if path.is_dir() or path.stat().st_size == 0:
        raise ValueError(f"{path} is {'a folder' if path.is_dir() else 'empty'}, not a model.pt written by train_atari")
    try:
        ckpt = torch.load(path, weights_only=False, map_location="cpu")
    except Exception as err:  # truncated, random bytes, another format
        raise ValueError(f"{path} is not a model.pt written by train_atari ({type(err).__name__}: {err})") from None
    need = ("n_actions", "actor", "preprocessing", "config")
    if not isinstance(ckpt, dict) or any(k not in ckpt for k in need):
        keys = sorted(ckpt) if isinstance(ckpt, dict) else type(ckpt).__name__
        raise ValueError(
            f"{path} is not an Atari checkpoint: it lacks {[k for k in need if k not in ckpt] if isinstance(ckpt, dict) else need} "
            f"(it has {keys}; a Taxi model.pt?)"
        )
    actor = make_atari_actor_critic(ckpt["n_actions"])[0]
    try:
        actor.load_state_dict(ckpt["actor"])
    except RuntimeError as err:
        raise ValueError(f"{path}: its actor does not fit the paper's Atari network ({err})") from None
    return actor.to(device), ckpt


def load_gym_expert(cfg, size: int, n_actions: int):
    """The expert policy of a vector-observation env (observations of ``size``): the actor
    of ``cfg.demo.expert`` (``model.pt`` of an earlier run of this pipeline on the same
    env), rebuilt from the settings stored beside its weights, or the callable it names
    (``module:function``, :mod:`torchrl_hybrid.experts.scripted`); ``None`` without one."""
    if not cfg.demo.expert:  # demos given as a file: the expert is only needed for its evaluation
        return None
    from torchrl_hybrid.experts.scripted import is_callable_spec, load_callable_expert

    if is_callable_spec(cfg.demo.expert):  # module:function, e.g. a scripted controller
        return load_callable_expert(cfg.demo.expert)
    path = Path(cfg.demo.expert)
    if not path.is_file():
        raise FileNotFoundError(
            f"demo.expert={path}: no such checkpoint; train an expert first "
            f"(variant=a2c out_dir=<dir>) and pass <dir>/model.pt"
        )
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
        saved, actor_state, enc = ckpt["config"], ckpt["actor"], ckpt["config"]["encoder"]
    except Exception as err:  # not a model.pt of this pipeline
        raise ValueError(f"demo.expert={path} is not a model.pt written by this pipeline ({err})") from err
    if saved["env"]["env_id"] != cfg.env.env_id or saved["env"].get("kwargs", {}) != cfg.env.kwargs:
        raise ValueError(
            f"demo.expert={path} was trained on {saved['env']['env_id']} {saved['env'].get('kwargs', {})}, "
            f"this run plays {cfg.env.env_id} {cfg.env.kwargs}"
        )
    actor, _ = make_mlp_actor_critic(size, n_actions, enc["hidden"], enc["num_layers"])
    actor.load_state_dict(actor_state)
    return actor.eval()
