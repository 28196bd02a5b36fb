"""``stray_light``: a scene-independent additive signal, smooth across the sensor.

Shape (fixed, documented): a paraboloid bright at the sensor centre and falling to half at
the corners, ``1 - 0.5·(r / r_corner)²``, normalised to mean 1 over the sensor; the
parameter ``mean_dn`` sets its mean per channel in DN (so it is defined in DN and needs the
per-channel gain to be expressed in simulator units).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from thintact_sdk.physics._spec import EffectSpec, ParamSpec

SPEC = EffectSpec(
    name="stray_light",
    stage="dn",
    description="light reaching the sensor without passing the mask adds a smooth glow",
    params={
        "mean_dn": ParamSpec("DN", [0.0, 0.0, 0.0], (0.0, 65535.0),
                             "mean added signal per channel (R, G, B)", shape=(3,))
    },
)


def shape(rows: int, cols: int) -> np.ndarray:
    """``R × S`` spatial shape with mean 1 (see module docstring)."""
    y = np.arange(rows) - (rows - 1) / 2
    x = np.arange(cols) - (cols - 1) / 2
    r2 = y[:, None] ** 2 + x[None, :] ** 2
    raw = 1.0 - 0.5 * r2 / max(float(r2.max()), 1e-12)
    return raw / raw.mean()


def apply(signal_dn: np.ndarray, mean_dn: Any) -> np.ndarray:
    """``F × R × S × C`` signal in DN (above black) plus the stray-light glow."""
    m = np.asarray(mean_dn, float)
    if not np.any(m):
        return signal_dn
    c = signal_dn.shape[-1]
    return signal_dn + shape(*signal_dn.shape[1:3])[None, :, :, None] * m[:c]
