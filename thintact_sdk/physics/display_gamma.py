"""``display_gamma``: the display (or membrane) emits ``value^gamma`` instead of ``value``."""

from __future__ import annotations

import numpy as np

from thintact_sdk.physics._spec import EffectSpec, ParamSpec

SPEC = EffectSpec(
    name="display_gamma",
    stage="scene",
    description="emitted radiance is the displayed value raised to a power (non-linear display)",
    params={"gamma": ParamSpec("1", 1.0, (0.2, 5.0), "exponent; 1 = linear display")},
)


def apply(scenes: np.ndarray, gamma: float) -> np.ndarray:
    """``F × N × M × C`` display values → radiance ``max(value, 0)^gamma`` (same shape)."""
    if gamma == 1.0:
        return scenes
    return np.power(np.clip(scenes, 0.0, None), gamma)
