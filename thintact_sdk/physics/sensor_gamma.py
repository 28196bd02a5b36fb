"""``sensor_gamma``: ``DN - black = FS·(L/FS)^gamma`` with ``L`` the linear signal in DN and
``FS = saturation_dn - black_level_dn``."""

from __future__ import annotations

import numpy as np

from thintact_sdk.physics._spec import EffectSpec, ParamSpec

SPEC = EffectSpec(
    name="sensor_gamma",
    stage="dn",
    description="the sensor's response is a power law of the light instead of linear",
    params={"gamma": ParamSpec("1", 1.0, (0.2, 5.0), "exponent; 1 = linear sensor")},
)


def apply(signal_dn: np.ndarray, gamma: float, full_scale_dn: float) -> np.ndarray:
    """Linear signal in DN above black → response in DN above black (same shape)."""
    if gamma == 1.0:
        return signal_dn
    return full_scale_dn * np.power(np.clip(signal_dn, 0.0, None) / full_scale_dn, gamma)
