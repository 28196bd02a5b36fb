"""``veiling_glare``: each channel gains ``fraction`` × (that frame's mean signal in it)."""

from __future__ import annotations

import numpy as np

from thintact_sdk.physics._spec import EffectSpec, ParamSpec

SPEC = EffectSpec(
    name="veiling_glare",
    stage="signal",
    description="scattered light adds a uniform veil proportional to the frame's mean brightness",
    params={"fraction": ParamSpec("1", 0.0, (0.0, 1.0), "veil / frame mean, per channel")},
)


def apply(signal: np.ndarray, fraction: float) -> np.ndarray:
    """``F × R × S × C`` → same, plus ``fraction·mean`` over rows and columns per frame/channel."""
    if fraction == 0:
        return signal
    return signal + fraction * signal.mean(axis=(1, 2), keepdims=True)
