"""``geometry``: the true scene-to-mask and mask-to-sensor distances differ from the
profile's (``None`` keeps the profile's value). Keeps the kernel separable."""

from __future__ import annotations

from thintact_sdk.physics._spec import EffectSpec, ParamSpec

SPEC = EffectSpec(
    name="geometry",
    stage="kernel",
    description="the real gaps between scene, mask and sensor are not the nominal ones",
    params={
        "scene_to_mask_mm": ParamSpec("mm", None, (0.01, 100.0), "true z; None = profile's"),
        "mask_to_sensor_mm": ParamSpec("mm", None, (0.001, 100.0), "true d; None = profile's"),
    },
)


def distances_mm(
    nominal_z_mm: float, nominal_d_mm: float, scene_to_mask_mm: float | None,
    mask_to_sensor_mm: float | None,
) -> tuple[float, float]:
    """``(z, d)`` in mm: the effect's values where given, else the nominal ones."""
    z = nominal_z_mm if scene_to_mask_mm is None else float(scene_to_mask_mm)
    d = nominal_d_mm if mask_to_sensor_mm is None else float(mask_to_sensor_mm)
    return z, d
