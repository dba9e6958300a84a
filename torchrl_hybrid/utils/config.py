"""Nested dataclass configs from plain (e.g. Hydra) dicts."""
from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

T = TypeVar("T")

__all__ = ["dataclass_from_dict"]


def dataclass_from_dict(cls: type[T], values: dict[str, Any], prefix: str = "") -> T:
    """Builds ``cls`` from nested dicts, recursing into dataclass-typed fields and
    rejecting unknown keys with a message that lists the known ones."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {}
    for k, v in dict(values).items():
        if k not in fields:
            raise ValueError(f"unknown config key {prefix + k!r}; known keys: {', '.join(fields)}")
        factory = fields[k].default_factory
        sub = factory if factory is not dataclasses.MISSING and dataclasses.is_dataclass(factory) else None
        kwargs[k] = dataclass_from_dict(sub, v, f"{prefix}{k}.") if sub is not None and isinstance(v, dict) else v
    return cls(**kwargs)
