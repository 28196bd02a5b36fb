"""``sensor_blur``: Gaussian blur in the sensor plane (optical / electrical pixel crosstalk).

Edges are mirrored (``reflect``).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from thintact_sdk.physics._spec import EffectSpec, ParamSpec

SPEC = EffectSpec(
    name="sensor_blur",
    stage="signal",
    description="light or charge spreads between neighbouring sensor pixels (Gaussian)",
    params={"sigma_um": ParamSpec("um", 0.0, (0.0, 1000.0), "standard deviation in the sensor plane")},
)


def apply(signal: np.ndarray, sigma_um: float, pitch_um: float) -> np.ndarray:
    """Blur ``F × R × S × C`` signals by ``sigma_um`` (sensor pixel pitch ``pitch_um``)."""
    if sigma_um <= 0:
        return signal
    s = sigma_um / pitch_um
    return gaussian_filter(np.asarray(signal, float), sigma=(0, s, s, 0), mode="reflect")
