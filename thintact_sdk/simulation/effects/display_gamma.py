"""``display_gamma``: the display (or membrane) emits ``value^gamma`` instead of ``value``."""

from __future__ import annotations

import numpy as np

from thintact_sdk.simulation.effects._spec import (
    DeviceProfile,
    EffectSpec,
    Params,
    ParamSpec,
    scalar_fit,
)


def apply(scenes: np.ndarray, gamma: float) -> np.ndarray:
    """``F × N × M × C`` display values → radiance ``max(value, 0)^gamma`` (same shape)."""
    if gamma == 1.0:
        return scenes
    return np.power(np.clip(scenes, 0.0, None), gamma)


def _forward(scenes: np.ndarray, params: Params, _profile: DeviceProfile) -> np.ndarray:
    return apply(scenes, params["gamma"])


def describe(params: Params, _p: DeviceProfile) -> str:
    """The finding in words."""
    return (
        f"The display is not linear: emitted radiance = value^{float(params['gamma']):.3f}; the "
        "model assumed radiance proportional to the value."
    )


SPEC = EffectSpec(
    name="display_gamma",
    stage="scene",
    order=0,
    description="emitted radiance is the displayed value raised to a power (non-linear display)",
    params={"gamma": ParamSpec("1", 1.0, (0.2, 5.0), "exponent; 1 = linear display")},
    forward=_forward,
    describe=describe,
    distinguish={"sensor_gamma": (
        "uniform grey frames at several display levels and one level at several exposures: "
        "display gamma bends the first series only, sensor gamma both"
    )},
    fit=scalar_fit("gamma", 1.0, 0.15, signed=True),
)
