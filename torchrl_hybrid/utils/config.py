"""Nested dataclass configs from plain (e.g. Hydra) dicts, with the types checked, and the checks each
config group's ``validate()`` states its rules with."""

from __future__ import annotations

import copy
import dataclasses
import math
import typing
from typing import Any, TypeVar

T = TypeVar("T")

__all__ = [
    "require",
    "dataclass_from_dict",
    "flatten_dict",
    "merge_dicts",
    "check_types",
    "check_int",
    "check_float",
    "MAX_COUNT",
    "MAX_FRAMES",
    "MAX_COEFF",
    "MAX_SEED",
    "MAX_THREADS",
]

# Ceilings of the validation (the schemas' validate methods): far above any real run, low enough that
# the values stay exact in float64 and int64 and their products (frames per batch, squared gradients of
# float32 losses) cannot overflow.
MAX_COUNT = 1_000_000  # sizes and counts: envs, layers, widths, batch sizes, episodes, updates
MAX_FRAMES = 10**12  # frame and step counts: total_frames, *_frames, episode lengths
MAX_COEFF = 1e6  # loss weights and other unbounded positive reals
MAX_SEED = 10**9  # seeds (the runs add offsets up to ~1e6 for their other streams; ALE takes int32)
MAX_THREADS = 1024

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
        hint is float and isinstance(value, int) and not isinstance(value, bool)
    )
    if not ok:
        raise ValueError(f"{key}={value!r} must be {_SCALARS[hint]}")
    return float(value) if hint is float else value


def require(ok: bool, msg: str) -> None:
    """Raises ``ValueError(msg)`` unless ``ok``: each config group's ``validate()`` states its
    rules with it, each message naming the setting and the fix."""
    if not ok:
        raise ValueError(msg)


def check_types(obj: Any, prefix: str = "", recurse: bool = True) -> None:
    """Every field of the dataclass ``obj`` (and, with ``recurse``, of its dataclass-valued
    fields) has its declared type: an int field an int (not a bool, not a float), a float
    field a number, a bool field a bool, a str field a str; else a ``ValueError`` naming the
    setting. Catches values set on a config object directly (``dataclass_from_dict`` checks
    the ones it builds)."""
    hints = typing.get_type_hints(type(obj))
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if dataclasses.is_dataclass(v):
            if recurse:
                check_types(v, f"{prefix}{f.name}.")
            continue
        _check(v, hints.get(f.name, Any), prefix + f.name)


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def check_int(name: str, value: Any, lo: int, cap: int = MAX_COUNT) -> None:
    """``value`` is an integer in ``[lo, cap]``, else a one-line ``ValueError`` naming ``name``."""
    if not (_is_int(value) and lo <= value <= cap):
        raise ValueError(f"{name} must be >= {lo} (an integer up to {cap:_}), got {value!r}")


def check_float(
    name: str,
    value: Any,
    lo: float,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
    cap: float = MAX_COEFF,
) -> None:
    """``value`` is a finite number (NaN and infinities refused) in the interval from ``lo`` to
    ``hi`` (open ends as asked), or, without ``hi``, above ``lo`` and at most ``cap``; else a
    one-line ``ValueError`` naming ``name``."""
    ok = (_is_int(value) or isinstance(value, float)) and math.isfinite(value)
    if ok:
        ok = (value > lo if lo_open else value >= lo) and (
            value <= cap if hi is None else (value < hi if hi_open else value <= hi)
        )
    if not ok:
        if hi is None:
            want = f"{'>' if lo_open else '>='} {lo:g} (a finite number up to {cap:g})"
        else:
            want = f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'} (a finite number)"
        raise ValueError(f"{name} must be {want}, got {value!r}")


def dataclass_from_dict(cls: type[T], values: dict[str, Any], prefix: str = "") -> T:
    """Builds ``cls`` from nested dicts the way Hydra does (``OmegaConf.structured``, merged
    with ``values``, then ``OmegaConf.to_object``), with OmegaConf's errors turned into one-line
    ``ValueError`` messages that name the setting: an unknown key lists the known ones, a value
    of the wrong type names the type wanted. The result's types are then checked strictly
    (:func:`check_types`)."""
    from omegaconf import OmegaConf
    from omegaconf.errors import ConfigKeyError, ValidationError

    _check_values(cls, values, prefix)
    try:
        obj = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(cls), values))
    except ConfigKeyError as err:
        full = str(err.full_key)
        parent, _, _ = full.rpartition(".")
        group: Any = cls
        for name in parent.split(".") if parent else ():
            group = next(f for f in dataclasses.fields(group) if f.name == name).default_factory
        known = ", ".join(f.name for f in dataclasses.fields(group))
        raise ValueError(f"unknown config key {prefix + full!r}; known keys: {known}") from None
    except ValidationError as err:
        hint = str(err).splitlines()[0]
        raise ValueError(f"{prefix}{err.full_key}: {hint}") from None
    check_types(obj, prefix)
    return typing.cast(T, obj)


def _check_values(cls: Any, values: Any, prefix: str) -> None:
    """The mistakes OmegaConf names less clearly, each refused with the setting and the fix: an
    unknown key (with the known ones), a group of settings given as a scalar (``loss=3``), a
    scalar of the wrong type (``seed='abc' must be an integer``)."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    for k, v in dict(values).items():
        if k not in fields:
            raise ValueError(f"unknown config key {prefix + k!r}; known keys: {', '.join(fields)}")
        sub = fields[k].default_factory
        if sub is not dataclasses.MISSING and dataclasses.is_dataclass(sub):
            if not isinstance(v, typing.Mapping):
                raise ValueError(f"{prefix + k}={v!r} must be a group of settings ({prefix + k}.<name>=...)")
            _check_values(sub, v, f"{prefix}{k}.")
        else:
            _check(v, hints.get(k, Any), prefix + k)


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
