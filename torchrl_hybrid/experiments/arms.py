"""Named arms of a comparison: a variant plus settings over the comparison's base, with the
arm it changes (``base``), whose AUC the analysis holds it against. Shared by the gymnasium
and Atari comparisons."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

__all__ = ["check_arms"]


def check_arms(
    arms: Mapping[str, dict],
    all_arms: Mapping[str, dict],
    variants: Iterable[str],
    requested: Iterable[str],
    settings: str = "settings over the base",
) -> None:
    """Raises ``ValueError`` naming the problem: a user arm (``arms``) that takes a variant's
    name or names no valid variant; an arm whose ``base`` is neither a variant nor another arm;
    a requested run that is neither a variant nor an arm."""
    variants = list(variants)
    for name, spec in arms.items():
        if name in variants:
            raise ValueError(f"arms.{name}: an arm cannot take a variant's name; call it e.g. {name}_mine")
        if not isinstance(spec, dict) or spec.get("variant") not in variants:
            raise ValueError(
                f"arms.{name} must be a mapping with variant: one of {variants} ({settings}), got {spec!r}"
            )
    for name, spec in all_arms.items():
        base = spec.get("base")
        if base is not None and (
            not isinstance(base, str) or base == name or base not in set(variants) | set(all_arms)
        ):
            raise ValueError(
                f"arms.{name}.base={base!r}: name the variant or arm this one adds an option to "
                f"(one of {variants} or {[a for a in all_arms if a != name]})"
            )
    bad = sorted(set(requested) - set(variants) - set(all_arms))
    if bad:
        raise ValueError(
            f"unknown variant(s) or arm(s) {bad}; choose from the variants {variants} or the arms {list(all_arms)}"
        )
