"""``mask_misalignment``: the pattern is evaluated at ``m' = Rot(-angle)·(m - (dx, dy))``;
``Rot(a)`` turns +x towards +y. A rotation breaks the separability of the kernel (the
simulator then uses its direct, non-separable path); a pure shift keeps it."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from thintact_sdk.simulation.effects._spec import (
    DeviceProfile,
    EffectSpec,
    FitSpec,
    Params,
    ParamSpec,
    const,
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


def _to_params(v: np.ndarray, _p: DeviceProfile) -> dict[str, Any]:
    return {"angle_deg": round(float(v[0]), 5), "dx_um": round(float(v[1]), 4),
            "dy_um": round(float(v[2]), 4)}


def _from_params(d: Params, _p: DeviceProfile) -> np.ndarray:
    return np.array([float(d.get("angle_deg", 0.0)), float(d.get("dx_um", 0.0)),
                     float(d.get("dy_um", 0.0))])


def describe(params: Params, _p: DeviceProfile) -> str:
    """The finding in words."""
    return (
        f"The mask is turned by {float(params['angle_deg']):+.3f}° and shifted by "
        f"({float(params['dx_um']):+.1f}, {float(params['dy_um']):+.1f}) um relative to the sensor; "
        "the model assumed it centred and square."
    )


SPEC = EffectSpec(
    name="mask_misalignment",
    stage="kernel",
    description="the mask is rotated and/or shifted relative to the sensor",
    params={
        "angle_deg": ParamSpec("deg", 0.0, (-10.0, 10.0), "rotation, +x towards +y"),
        "dx_um": ParamSpec("um", 0.0, (-2000.0, 2000.0), "shift along x (columns)"),
        "dy_um": ParamSpec("um", 0.0, (-2000.0, 2000.0), "shift along y (rows)"),
    },
    kernel=lambda params, _p: {k: params[k] for k in ("angle_deg", "dx_um", "dy_um")},
    describe=describe,
    fit=FitSpec(
        "optical", ("angle_deg", "dx_um", "dy_um"), const(0.0, 0.0, 0.0), const(0.3, 5.0, 5.0),
        _to_params, _from_params, signed=(True, True, True),
        # the rotated kernel's rank grows with the angle: the score's derivative is taken at
        # 0.05° (rotated + refracted virtual-mini kernel 2.9 s CPU there, 25 s at 0.3°)
        score_step=const(0.05, 5.0, 5.0),
        costly=True,  # every rotated kernel is rebuilt (seconds each)
    ),
)
