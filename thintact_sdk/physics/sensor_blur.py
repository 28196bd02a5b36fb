"""``sensor_blur``: Gaussian blur in the sensor plane (optical / electrical pixel crosstalk).

The blur is integrated over the pixels (see :mod:`thintact_sdk.physics._blur`). Edges are
mirrored (``reflect``).
"""

from __future__ import annotations

import numpy as np

from thintact_sdk.physics._blur import blur_pixels
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
    return blur_pixels(signal, sigma_um / pitch_um, axes=(1, 2))
