"""Physical effects the baseline simulation leaves out (CONTRACTS §5), one module each.

``EFFECTS`` maps every effect name to its :class:`EffectSpec` (parameters with units,
defaults, physical bounds, a one-line description). A profile switches effects on by
listing them in ``profile.physics``; :func:`resolve_physics` validates such a dict and fills
in the defaults. :class:`thintact_sdk.imaging.simulator.Simulator` applies them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from thintact_sdk.errors import ThinTactError
from thintact_sdk.physics import (
    color_crosstalk,
    diffraction,
    display_gamma,
    geometry,
    mask_leakage,
    mask_misalignment,
    pixel_angular_response,
    refraction,
    saturation,
    scene_blur,
    sensor_blur,
    sensor_gamma,
    stray_light,
    veiling_glare,
)
from thintact_sdk.physics._spec import STAGES, EffectSpec, ParamSpec

__all__ = ["EFFECTS", "STAGES", "EffectSpec", "ParamSpec", "PhysicsError", "resolve_physics"]

EFFECTS: dict[str, EffectSpec] = {
    m.SPEC.name: m.SPEC
    for m in (
        diffraction, pixel_angular_response, refraction, mask_misalignment, mask_leakage,
        geometry, sensor_gamma, saturation, sensor_blur, scene_blur, display_gamma,
        color_crosstalk, veiling_glare, stray_light,
    )
}


class PhysicsError(ThinTactError):
    """A ``physics`` entry names an unknown effect or parameter, or a value out of bounds."""


def _check_value(effect: str, name: str, spec: ParamSpec, value: Any) -> Any:
    if value is None and spec.default is None:
        return None
    arr = np.asarray(value, dtype=float)
    if spec.shape and arr.shape != spec.shape:
        raise PhysicsError(
            f"physics.{effect}.{name}: expected shape {list(spec.shape)}, got {list(arr.shape)}"
        )
    if not spec.shape and arr.ndim != 0:
        raise PhysicsError(f"physics.{effect}.{name}: expected a number, got {value!r}")
    if not np.all(np.isfinite(arr)):
        raise PhysicsError(f"physics.{effect}.{name}: values must be finite")
    lo, hi = spec.bounds
    if np.any(arr < lo) or np.any(arr > hi):
        unit = "" if spec.unit == "1" else f" {spec.unit}"
        raise PhysicsError(
            f"physics.{effect}.{name}: {value!r} outside the physical range [{lo}, {hi}]{unit}"
        )
    return arr.tolist() if spec.shape else float(arr)


def resolve_physics(physics: dict[str, dict[str, Any]] | None) -> dict[str, dict[str, Any]]:
    """Validate a ``physics`` dict and fill in every effect's missing parameters.

    Returns
    -------
    dict
        ``{effect: {param: value}}`` with floats / nested lists, in :data:`EFFECTS` order.

    Raises
    ------
    PhysicsError
        Unknown effect or parameter, wrong shape, or a value outside its bounds.
    """
    physics = physics or {}
    out: dict[str, dict[str, Any]] = {}
    for name in physics:
        if name not in EFFECTS:
            raise PhysicsError(
                f"physics: unknown effect {name!r}; known effects: {', '.join(EFFECTS)}"
            )
    for name, spec in EFFECTS.items():
        if name not in physics:
            continue
        given = physics[name] or {}
        if not isinstance(given, dict):
            raise PhysicsError(f"physics.{name}: expected a mapping of parameters")
        for p in given:
            if p not in spec.params:
                raise PhysicsError(
                    f"physics.{name}: unknown parameter {p!r}; "
                    f"parameters: {', '.join(spec.params) or '(none)'}"
                )
        params = {}
        for p, ps in spec.params.items():
            params[p] = _check_value(name, p, ps, given.get(p, ps.default))
        if name == "color_crosstalk":
            color_crosstalk.check_diagonal(params["matrix"])
        out[name] = params
    return out
