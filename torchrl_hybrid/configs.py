"""Hydra structured configs: the dataclasses of the run assembly as ConfigStore schemas,
so that every default is written once (in the dataclass) and Hydra checks every
command-line setting's name and type against it.

Stored (after :func:`register_configs`):

- ``gym_schema``: :class:`~torchrl_hybrid.families.gym.GymConfig` (gymnasium envs);
  ``atari_schema``: :class:`~torchrl_hybrid.families.atari.AtariConfig`;
- the groups the two share, one entry per env family, for configs of your own:
  ``loss/{taxi,atari}``, ``optim/{taxi,atari}``, ``logger/{gym,atari}``,
  ``demo/{gym,atari}``, ``env/{gym,atari}``.

The recipes' YAML files (``recipes/config/``) start from these schemas and set only what
differs (a timestamped ``out_dir``, a preset's env). ``python recipes/train.py --cfg job``
prints the whole composed config.
"""

from __future__ import annotations

__all__ = ["register_configs"]

_REGISTERED = False


def register_configs() -> None:
    """Stores the schemas in Hydra's ConfigStore (once per process)."""
    global _REGISTERED
    if _REGISTERED:
        return
    from hydra.core.config_store import ConfigStore

    from torchrl_hybrid.families import atari, gym
    from torchrl_hybrid.trainers import config as shared

    cs = ConfigStore.instance()
    cs.store(name="gym_schema", node=gym.GymConfig)
    cs.store(name="atari_schema", node=atari.AtariConfig)
    for group, entries in {
        "loss": {"taxi": shared.LossConfig, "atari": atari.AtariLossConfig},
        "optim": {"taxi": shared.OptimConfig, "atari": atari.AtariOptimConfig},
        "logger": {"gym": gym.GymLoggerConfig, "atari": atari.AtariLoggerConfig},
        "demo": {"gym": gym.GymDemoConfig, "atari": atari.AtariDemoConfig},
        "env": {"gym": gym.EnvConfig, "atari": atari.AtariEnvConfig},
    }.items():
        for name, node in entries.items():
            cs.store(group=group, name=name, node=node)
    _REGISTERED = True
