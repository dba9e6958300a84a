"""Nested dataclass configs from plain (e.g. Hydra) dicts, with the types checked."""
from __future__ import annotations

import copy
import dataclasses
import typing
from typing import Any, TypeVar

T = TypeVar("T")

__all__ = ["dataclass_from_dict", "flatten_dict", "merge_dicts"]

_SCALARS = {int: "an integer", float: "a number", bool: "true or false", str: "a string"}


def _check(value: Any, hint: Any, key: str) -> Any:
    """``value`` as the field's type (an int is accepted for a float field), or a
    ``ValueError`` naming the setting, e.g. ``seed='abc' must be an integer``."""
    args = typing.get_args(hint)
    if type(None) in args:  # Optional[X] / X | None
        if value is None:
            return None
        rest = [a for a in args if a is not type(None)]
        hint = rest[0] if len(rest) == 1 else Any
    if hint not in _SCALARS:
        return value
    ok = (isinstance(value, hint) and not (hint is int and isinstance(value, bool))) or (
        hint is float and isinstance(value, int) and not isinstance(value, bool))
    if not ok:
        raise ValueError(f"{key}={value!r} must be {_SCALARS[hint]}")
    return float(value) if hint is float else value


def dataclass_from_dict(cls: type[T], values: dict[str, Any], prefix: str = "") -> T:
    """Builds ``cls`` from nested dicts, recursing into dataclass-typed fields,
    rejecting unknown keys with a message that lists the known ones, and values of
    the wrong type with a message naming the setting."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for k, v in dict(values).items():
        if k not in fields:
            raise ValueError(f"unknown config key {prefix + k!r}; known keys: {', '.join(fields)}")
        factory = fields[k].default_factory
        sub = factory if factory is not dataclasses.MISSING and dataclasses.is_dataclass(factory) else None
        if sub is not None:
            if not isinstance(v, dict):
                raise ValueError(f"{prefix + k}={v!r} must be a group of settings ({prefix + k}.<name>=...)")
            kwargs[k] = dataclass_from_dict(sub, v, f"{prefix}{k}.")
        else:
            kwargs[k] = _check(v, hints.get(k, Any), prefix + k)
    return cls(**kwargs)


def merge_dicts(a: dict, b: dict) -> dict:
    """A deep copy of ``a`` with ``b`` merged in: nested dicts merge key by key, any other
    value of ``b`` replaces ``a``'s (how the studies put per-run settings over a base)."""
    out = copy.deepcopy(a)
    for k, v in b.items():
        out[k] = merge_dicts(out.get(k, {}), v) if isinstance(v, dict) else v
    return out


def flatten_dict(d: dict, prefix: str = "") -> dict[str, Any]:
    """Nested dicts as one level of dotted keys: ``{"loss": {"bc_coeff": 1}}`` ->
    ``{"loss.bc_coeff": 1}``."""
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(flatten_dict(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out
