"""Named arms of a comparison: a variant plus settings over the comparison's base, with the
arm it changes (``base``), whose AUC the analysis holds it against. Shared by the gymnasium
and Atari comparisons."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

__all__ = ["ARMS_DIR", "check_arms", "named_arms"]

#: the named arms of each study live in the recipes' configs: recipes/config/arms/<family>.yaml
ARMS_DIR = Path(__file__).resolve().parents[2] / "recipes" / "config" / "arms"


def named_arms(family: str) -> dict[str, dict]:
    """The named arms of ``family``'s comparison (``"gym"``, ``"atari"``), read from
    ``recipes/config/arms/<family>.yaml``; ``{}`` where that file is absent (a package installed
    without the recipes: then a comparison takes variants and the arms it is given)."""
    from omegaconf import OmegaConf

    path = ARMS_DIR / f"{family}.yaml"
    if not path.exists():
        return {}
    arms = OmegaConf.to_container(OmegaConf.load(path), resolve=True)
    if not isinstance(arms, dict) or not all(isinstance(v, dict) for v in arms.values()):
        raise ValueError(f"{path} must map each arm's name to {{variant: ..., <settings>}}")
    return {str(k): v for k, v in arms.items()}  # type: ignore[misc]


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
            f"unknown variant(s) or arm(s) {bad}; choose from the variants {variants} or the arms "
            f"{list(all_arms)} (named arms: {ARMS_DIR}/<family>.yaml; your own: compare.arms)"
        )
