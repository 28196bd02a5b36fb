"""Plain words for findings: what the model left out, and what recording would tell two
equally good explanations apart.

The sentences about a particular effect are the effect's own (``describe`` and
``distinguish`` of its :class:`~thintact_sdk.simulation.effects.EffectSpec`); this module only
frames them.
"""

from __future__ import annotations

from typing import Any

from thintact_sdk.formats.profiles import Profile
from thintact_sdk.simulation.effects import EFFECTS


def describe_effect(name: str, params: dict[str, Any], p: Profile) -> str:
    """One sentence: the physics the model left out, with its fitted size."""
    spec = EFFECTS.get(name)
    if spec is not None and spec.describe is not None:
        return spec.describe(params, p)
    what = spec.description if spec is not None else name
    return f"{name} ({what}): {params}"


def tell_apart(a: str, b: str, frame_hint: str) -> str:
    """What recording would separate effects ``a`` and ``b`` (either may declare it)."""
    hints = [
        EFFECTS[x].distinguish.get(y) for x, y in ((a, b), (b, a)) if x in EFFECTS
    ]
    base = next((h for h in hints if h), None)
    txt = f"To tell {a} from {b}: "
    if base:
        txt += base + "; "
    return txt + frame_hint
