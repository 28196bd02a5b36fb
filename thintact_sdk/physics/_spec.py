"""Typed description of an effect of CONTRACTS §5 and of its parameters."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

STAGES = ("scene", "kernel", "signal", "dn")
"""Where an effect acts: on the scene before imaging, inside the imaging kernel, on the
linear signal (unit-free, linear), or on the signal in DN (needs the per-channel gain)."""


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: unit, default, physical bounds (applied to every element of a list)."""

    unit: str
    default: Any
    bounds: tuple[float, float]
    description: str = ""
    shape: tuple[int, ...] = ()


@dataclass(frozen=True)
class EffectSpec:
    """An effect: its name, the stage it acts in, its parameters and a plain-words line."""

    name: str
    stage: str
    description: str
    params: dict[str, ParamSpec] = field(default_factory=dict)

    def defaults(self) -> dict[str, Any]:
        """The parameters at their neutral defaults (the effect then changes nothing)."""
        return {k: p.default for k, p in self.params.items()}
