"""Physical effects the baseline simulation leaves out (CONTRACTS §5), one module each.

``EFFECTS`` maps every effect name to its :class:`EffectSpec`: stage, parameters with units,
defaults and physical bounds, how it is applied, its words and how the diagnosis fits it
(see :mod:`thintact_sdk.simulation.effects._spec`). A profile switches effects on by listing them in
``profile.physics``; :func:`resolve_physics` validates such a dict and fills in the
defaults. :class:`thintact_sdk.simulation.simulator.Simulator` applies them stage by stage
(:func:`stage_effects`) and :mod:`thintact_sdk.diagnosis.imaging` fits them.

A new effect is one module with a ``SPEC``, added with :func:`register_effect`.
"""

from __future__ import annotations

from collections.abc import Iterable
from types import ModuleType
from typing import Any

import numpy as np

from thintact_sdk.errors import ThinTactError
from thintact_sdk.simulation.effects import (
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
from thintact_sdk.simulation.effects._spec import (
    STAGES,
    DataSearch,
    EffectSpec,
    FitSpec,
    ParamSpec,
    Proxy,
    Stage,
)

__all__ = [
    "EFFECTS", "STAGES", "DataSearch", "EffectSpec", "FitSpec", "ParamSpec", "PhysicsError",
    "Proxy", "Stage", "register_effect", "resolve_physics", "stage_effects", "unregister_effect",
    "window_blocker",
]


class PhysicsError(ThinTactError):
    """A ``physics`` entry names an unknown effect or parameter, or a value out of bounds."""


EFFECTS: dict[str, EffectSpec] = {}
"""Every known effect by name, in registration order (the order the diagnosis tries them)."""
_BUILT_IN = frozenset({
    "pixel_angular_response", "diffraction", "refraction", "mask_misalignment", "mask_leakage",
    "geometry", "sensor_blur", "scene_blur", "display_gamma", "color_crosstalk",
    "veiling_glare", "sensor_gamma", "saturation", "stray_light",
})


def register_effect(effect: EffectSpec | ModuleType, *, replace: bool = False) -> EffectSpec:
    """Add an effect (its :class:`EffectSpec`, or a module with a ``SPEC``) to :data:`EFFECTS`.

    The simulator then applies it in its stage and the diagnosis tries it (when it declares
    a ``fit``). Returns the spec.

    Raises
    ------
    PhysicsError
        The name is taken (unless ``replace``), or a module has no ``SPEC``.
    """
    spec = getattr(effect, "SPEC", None) if isinstance(effect, ModuleType) else effect
    if not isinstance(spec, EffectSpec):
        raise PhysicsError(f"register_effect: {effect!r} is not an EffectSpec nor a module with a SPEC")
    if spec.name in EFFECTS and not replace:
        raise PhysicsError(f"register_effect: an effect named {spec.name!r} is already registered")
    EFFECTS[spec.name] = spec
    return spec


def unregister_effect(name: str) -> None:
    """Remove an effect added by :func:`register_effect` (the CONTRACTS §5 ones stay)."""
    if name in _BUILT_IN:
        raise PhysicsError(f"unregister_effect: {name!r} is a CONTRACTS §5 effect")
    EFFECTS.pop(name, None)


def window_blocker(names: Iterable[str]) -> str | None:
    """Why a window of the sensor cannot be evaluated alone with the effects ``names`` (the
    first after the kernel that reads beyond its pixel, ``EffectSpec.reads_beyond_pixel``),
    or None when it can. Names that are no effect are ignored."""
    for name in names:
        spec = EFFECTS.get(name)
        if spec is not None and spec.stage != "kernel" and spec.reads_beyond_pixel is not None:
            return f"{name} gives each pixel {spec.reads_beyond_pixel}: a window of the sensor cannot be evaluated alone"
    return None


def stage_effects(stage: Stage) -> list[EffectSpec]:
    """The effects acting in ``stage``, in the order they are applied."""
    found = [s for s in EFFECTS.values() if s.stage == stage]
    return sorted(found, key=lambda s: s.order)


for _module in (
    pixel_angular_response, diffraction, refraction, mask_misalignment, mask_leakage, geometry,
    sensor_blur, scene_blur, display_gamma, color_crosstalk, veiling_glare, sensor_gamma,
    saturation, stray_light,
):
    register_effect(_module)


def _check_value(effect: str, name: str, spec: ParamSpec, value: Any) -> Any:
    if value is None and spec.default is None:
        return None
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):  # a mapping, text, ragged lists, a 400-digit int
        raise PhysicsError(f"physics.{effect}.{name}: expected "
                           f"{'numbers of shape ' + str(list(spec.shape)) if spec.shape else 'a number'}, "
                           f"got {str(value)[:60]!r}") from None
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
        if spec.validate is not None:
            spec.validate(params)
        out[name] = params
    return out
