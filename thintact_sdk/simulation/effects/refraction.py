"""``refraction``: the scene-to-mask gap (thickness z) has index ``n``; the mask-to-sensor
gap (d) is air. A ray reaching the sensor at angle θ (air) travels at θ' in the medium
with ``sin θ = n sin θ'``; its lateral run is ``ρ(θ) = d·tan θ + z·tan θ'`` and it crosses
the mask at ``m = u + (s - u)·d·tan θ / ρ``.

Irradiance (radiance conserved as ``L/n²`` across the interface, Fresnel losses ignored):
``dE = (L/n²)·cos θ·dΩ``, ``dΩ/dA_s = sin θ / (ρ·dρ/dθ)``, so the factor is
``cos^(1+p) θ · sin θ / (n²·ρ·dρ/dθ)`` (``p`` the pixel angular exponent); for ``n = 1`` it is
``cos^(4+p) θ / H²``. The mapping ``m(u, s)`` is not linear; the simulator integrates the
mask along it per axis with the other axis's offset frozen per pixel pair
(:mod:`thintact_sdk.simulation.refracted`), which keeps the kernel separable.
"""

from __future__ import annotations

import numpy as np

from thintact_sdk.simulation.effects._spec import (
    DeviceProfile,
    EffectSpec,
    Params,
    ParamSpec,
    Proxy,
    scalar_fit,
)


def lateral_run_mm(theta: np.ndarray, z_mm: float, d_mm: float, n: float) -> np.ndarray:
    """``ρ(θ) = d·tan θ + z·tan θ'`` in mm for air angles ``theta`` (rad)."""
    tp = np.arcsin(np.sin(theta) / n)
    return d_mm * np.tan(theta) + z_mm * np.tan(tp)


def solve_air_angle(rho_mm: np.ndarray, z_mm: float, d_mm: float, n: float,
                    iterations: int = 60) -> np.ndarray:
    """Air angle θ (rad) of the ray whose lateral run is ``rho_mm``.

    Solved for ``t = tan θ`` by safeguarded Newton steps inside the bracket
    ``ρ/(d + z/n) ≤ t ≤ ρ/d`` (``ρ(t)`` is increasing; ``tan θ' ≤ tan θ / n``).
    """
    rho = np.asarray(rho_mm, float)
    lo = rho / (d_mm + z_mm / n)
    hi = rho / d_mm
    t = lo.copy()
    for _ in range(iterations):
        sin_t = t / np.sqrt(1 + t**2)
        sin_p = sin_t / n
        cos_p = np.sqrt(1 - sin_p**2)
        f = d_mm * t + z_mm * sin_p / cos_p - rho
        if np.all(np.abs(f) <= 1e-13 * (1 + rho)):
            break
        lo = np.where(f < 0, t, lo)
        hi = np.where(f > 0, t, hi)
        # d(sinθ)/dt = (1+t²)^(-3/2); d(tanθ')/d(sinθ') = 1/cos³θ'
        df = d_mm + z_mm / (n * cos_p**3) * (1 + t**2) ** -1.5
        t_new = t - f / df
        bad = (t_new <= lo) | (t_new >= hi) | ~np.isfinite(t_new)
        t = np.where(bad, (lo + hi) / 2, t_new)
    return np.arctan(t)


def crossing_fraction_and_factor(
    rho_mm: np.ndarray, z_mm: float, d_mm: float, n: float, exponent: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """``(kappa, factor)`` at lateral offsets ``rho_mm``.

    ``kappa = d·tan θ / ρ`` places the mask crossing at ``u + (s - u)·kappa``; ``factor`` is
    the irradiance per unit scene radiance and scene area (1/mm²).
    """
    rho = np.asarray(rho_mm, float)
    theta = solve_air_angle(rho, z_mm, d_mm, n)
    sin_t, cos_t = np.sin(theta), np.cos(theta)
    cos_p = np.sqrt(1 - (sin_t / n) ** 2)
    drho = d_mm / cos_t**2 + z_mm / cos_p**2 * cos_t / (n * cos_p)
    small = rho < 1e-9
    safe_rho = np.where(small, 1.0, rho)
    kappa0 = d_mm / (d_mm + z_mm / n)
    kappa = np.where(small, kappa0, d_mm * sin_t / cos_t / safe_rho)
    sin_over_rho = np.where(small, 1.0 / (d_mm + z_mm / n), sin_t / safe_rho)
    factor = cos_t ** (1 + exponent) * sin_over_rho / (n**2 * drho)
    return kappa, factor


def from_geometry_fit(geometry_fit: np.ndarray, p: DeviceProfile) -> np.ndarray | None:
    """Start for the fit: near the axis refraction acts like a shorter scene gap (z/n at the
    same d), so when the geometry fit (``scene_to_mask_mm, mask_to_sensor_mm``) shortens
    z/d, n = (z/d)_profile / (z/d)_fit; None when it does not."""
    ratio0 = p.geometry.scene_to_mask_mm / p.geometry.mask_to_sensor_mm
    ratio = float(geometry_fit[0] / geometry_fit[1])
    if ratio > 0.995 * ratio0:
        return None
    return np.array([ratio0 / ratio])


STAND_IN_MIN_INDEX = 1.1
"""Smallest index a geometry finding must imply (its scene gap at least 9 % shorter, relative
to the mask gap, than the profile's) to be named as possibly refraction where refraction
could not be screened: an assembly error of that size is rarer than an elastomer, acrylic or
glass gap (n 1.4-1.5); smaller shortenings are left to the geometry finding alone."""


def plausible_stand_in(start: np.ndarray) -> bool:
    """Whether a geometry fit implying index ``start[0]`` may be refraction in disguise."""
    return bool(start[0] >= STAND_IN_MIN_INDEX)


def describe(params: Params, p: DeviceProfile) -> str:
    """The finding in words."""
    n = float(params["n_scene_side"])
    z = p.geometry.scene_to_mask_mm
    return (
        f"The {z:g} mm scene-to-mask gap is a medium of refractive index {n:.3f} (elastomer, "
        f"glass), not air: rays bend at the mask, so the scene looks about {z / n:.2f} mm away "
        "near the axis; the model assumed straight rays in air."
    )


SPEC = EffectSpec(
    name="refraction",
    stage="kernel",
    description="the elastomer between scene and mask bends the rays (Snell's law)",
    params={"n_scene_side": ParamSpec("1", 1.0, (1.0, 3.0), "refractive index of the scene-to-mask gap")},
    kernel=lambda params, _p: {"n_scene_side": params["n_scene_side"]},
    describe=describe,
    distinguish={"geometry": (
        "a measured gap (or a second recording with the scene at another distance), or scenes with "
        "bright content far off-axis, where Snell's law departs from a changed straight-ray distance"
    )},
    # started from the geometry fit (near the axis refraction acts like a shorter scene gap)
    fit=scalar_fit("n_scene_side", 1.0, 0.4, signed=False,
                   proxy=Proxy("geometry", from_geometry_fit, stand_in=plausible_stand_in)),
)
