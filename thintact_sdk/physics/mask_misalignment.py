"""``mask_misalignment``: the pattern is evaluated at ``m' = Rot(-angle)·(m - (dx, dy))``;
``Rot(a)`` turns +x towards +y. A rotation breaks the separability of the kernel (the
simulator then uses its direct, non-separable path); a pure shift keeps it."""

from __future__ import annotations

import math

import numpy as np

from thintact_sdk.physics._spec import EffectSpec, ParamSpec

SPEC = EffectSpec(
    name="mask_misalignment",
    stage="kernel",
    description="the mask is rotated and/or shifted relative to the sensor",
    params={
        "angle_deg": ParamSpec("deg", 0.0, (-10.0, 10.0), "rotation, +x towards +y"),
        "dx_um": ParamSpec("um", 0.0, (-2000.0, 2000.0), "shift along x (columns)"),
        "dy_um": ParamSpec("um", 0.0, (-2000.0, 2000.0), "shift along y (rows)"),
    },
)


def pattern_coordinates(
    mx_mm: np.ndarray, my_mm: np.ndarray, angle_deg: float, dx_um: float, dy_um: float
) -> tuple[np.ndarray, np.ndarray]:
    """Mask-plane points ``(mx, my)`` (mm) → coordinates in the mask pattern's frame (mm)."""
    a = math.radians(angle_deg)
    x = np.asarray(mx_mm) - dx_um * 1e-3
    y = np.asarray(my_mm) - dy_um * 1e-3
    c, s = math.cos(a), math.sin(a)
    # Rot(-a) = [[c, s], [-s, c]]
    return c * x + s * y, -s * x + c * y
