"""``geometry``: the true scene-to-mask and mask-to-sensor distances differ from the
profile's (``None`` keeps the profile's value). Keeps the kernel separable."""

from __future__ import annotations

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


def distances_mm(
    nominal_z_mm: float, nominal_d_mm: float, scene_to_mask_mm: float | None,
    mask_to_sensor_mm: float | None,
) -> tuple[float, float]:
    """``(z, d)`` in mm: the effect's values where given, else the nominal ones."""
    z = nominal_z_mm if scene_to_mask_mm is None else float(scene_to_mask_mm)
    d = nominal_d_mm if mask_to_sensor_mm is None else float(mask_to_sensor_mm)
    return z, d


def _kernel(params: Params, p: DeviceProfile) -> dict[str, Any]:
    z, d = distances_mm(p.geometry.scene_to_mask_mm, p.geometry.mask_to_sensor_mm,
                        params.get("scene_to_mask_mm"), params.get("mask_to_sensor_mm"))
    return {"z_mm": z, "d_mm": d}


def _null(p: DeviceProfile) -> np.ndarray:
    return np.array([p.geometry.scene_to_mask_mm, p.geometry.mask_to_sensor_mm])


def _to_params(v: np.ndarray, _p: DeviceProfile) -> dict[str, Any]:
    return {"scene_to_mask_mm": round(float(v[0]), 5), "mask_to_sensor_mm": round(float(v[1]), 5)}


def _from_params(d: Params, p: DeviceProfile) -> np.ndarray:
    z, dd = distances_mm(p.geometry.scene_to_mask_mm, p.geometry.mask_to_sensor_mm,
                         d.get("scene_to_mask_mm"), d.get("mask_to_sensor_mm"))
    return np.array([z, dd])


def describe(params: Params, p: DeviceProfile) -> str:
    """The finding in words."""
    z, d = float(params["scene_to_mask_mm"]), float(params["mask_to_sensor_mm"])
    return (
        f"The gaps differ from the profile: scene-to-mask {z:.3f} mm (profile "
        f"{p.geometry.scene_to_mask_mm:g}), mask-to-sensor {d:.3f} mm (profile "
        f"{p.geometry.mask_to_sensor_mm:g}); the shadow of the mask is magnified differently."
    )


SPEC = EffectSpec(
    name="geometry",
    stage="kernel",
    description="the real gaps between scene, mask and sensor are not the nominal ones",
    params={
        "scene_to_mask_mm": ParamSpec("mm", None, (0.01, 100.0), "true z; None = profile's"),
        "mask_to_sensor_mm": ParamSpec("mm", None, (0.001, 100.0), "true d; None = profile's"),
    },
    kernel=_kernel,
    describe=describe,
    fit=FitSpec("optical", ("scene_to_mask_mm", "mask_to_sensor_mm"), _null, const(0.15, 0.03),
                _to_params, _from_params, signed=(True, True)),
)
