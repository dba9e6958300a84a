"""State-only demos from a Minari dataset.

The dataset is read from the local Minari cache (``MINARI_DATASETS_PATH``, by default
``~/.minari/datasets``) with Minari's own ``load_dataset`` / ``iterate_episodes``: nothing
is downloaded. Each episode's state sequence becomes expert pairs (s, s') with ``step``
and ``trajectory`` indices (:func:`~torchrl_hybrid.data.pairs_from_trajectories`); the
recorded actions are dropped on load, or, with ``keep_actions=True``, kept under
``EXPERT_ACTION_KEY`` for diagnostics only (the expert buffer never hands them to the
learner).

TorchRL's ``MinariExperienceReplay(..., load_from_local_minari=True)`` was tried first and
does not fit here: in TorchRL 0.14 its local path leaves every transition's ``episode``
index and ``terminated`` / ``truncated`` flags at 0, so the episodes (and the curriculum's
step within an episode) cannot be recovered from it.

    demos, meta = load_minari_demos("cartpole/expert-v0")
    python recipes/train.py --config-name cartpole demo.minari=cartpole/expert-v0
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict

from torchrl_hybrid.data.expert import pairs_from_trajectories, validate_demos

__all__ = ["load_minari_demos", "minari_datasets_path"]


def minari_datasets_path(path: str | os.PathLike | None = None) -> Path:
    """The local Minari cache: ``path``, else ``MINARI_DATASETS_PATH``, else ``~/.minari/datasets``."""
    if path is not None:
        return Path(path).expanduser()
    return Path(os.environ.get("MINARI_DATASETS_PATH", "~/.minari/datasets")).expanduser()


def load_minari_demos(
    dataset_id: str,
    *,
    datasets_path: str | os.PathLike | None = None,
    keep_actions: bool = False,
    obs_shape=None,
    obs_dtype: torch.dtype | None = None,
) -> tuple[TensorDict, dict[str, Any]]:
    """The expert pairs of the local Minari dataset ``dataset_id`` and its metadata
    (``env_id``, ``env_kwargs``: the env it was recorded on, when the dataset names one;
    ``total_episodes``, ``total_steps``, ``dataset_id``).

    ``obs_shape`` / ``obs_dtype``: what the env produces; demos of another shape or kind
    are refused. Raises ``FileNotFoundError`` (with where it looked) when the dataset is
    not in the local cache, ``ImportError`` naming the install command without Minari."""
    try:
        import h5py  # noqa: F401
        import minari
    except ImportError:
        raise ImportError(
            "demo.minari needs Minari with its HDF5 storage: pip install 'minari[hdf5]' (or pip install -e '.[minari]')"
        ) from None
    root = minari_datasets_path(datasets_path)
    h5 = root / dataset_id / "data" / "main_data.hdf5"
    if not h5.exists():
        raise FileNotFoundError(
            f"demo.minari={dataset_id}: no such dataset in the local Minari cache {root} "
            f"(looked for {h5}); nothing is downloaded. Create it there with "
            "minari.create_dataset_from_buffers / minari.DataCollector, or point "
            "MINARI_DATASETS_PATH (demo.minari_path) at the folder that holds it"
        )
    previous = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(root)  # Minari reads its cache from there
    try:
        dataset = minari.load_dataset(dataset_id)
        states, actions = [], []
        for episode in dataset.iterate_episodes():
            obs = episode.observations
            if not isinstance(obs, np.ndarray):
                raise ValueError(
                    f"demo.minari={dataset_id}: observations are {type(obs).__name__} (a dict or tuple "
                    "space); this pipeline takes flat or discrete observations"
                )
            obs = torch.as_tensor(obs)
            states.append(obs if obs.dtype.is_floating_point else obs.long())  # discrete states index tables
            actions.append(torch.as_tensor(np.asarray(episode.actions)))
        env_spec = dataset.spec.env_spec
    finally:
        if previous is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = previous
    if not states:
        raise ValueError(f"demo.minari={dataset_id}: the dataset holds no episodes")
    pairs = pairs_from_trajectories(states, actions if keep_actions else None)
    validate_demos(pairs, obs_shape=obs_shape, obs_dtype=obs_dtype, source=f"demo.minari={dataset_id}")
    env_id = getattr(env_spec, "id", None)
    env_kwargs = dict(getattr(env_spec, "kwargs", None) or {}) if env_spec is not None else None
    meta = {
        "dataset_id": dataset_id,
        "env_id": env_id,
        "env_kwargs": env_kwargs,
        "total_episodes": len(states),
        "total_steps": int(pairs.batch_size.numel()),
        "source": str(root / dataset_id),
    }
    return pairs, meta
