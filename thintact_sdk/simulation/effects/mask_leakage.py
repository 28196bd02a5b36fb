"""``mask_leakage``: closed cells pass a fraction ``t`` of the light.

Applies to the K×K cells only; the area outside the mask stays opaque. Intensity
transmittance inside the area: ``t + (1 - t)·(1 + φ_r φ_c)/2``, i.e. the open half is scaled by
``(1 + t)`` and the coding half by ``(1 - t)``; for diffraction the amplitude transmittance
``sqrt(t)`` is used the same way. Keeps the kernel separable.
"""

from __future__ import annotations

import math

from thintact_sdk.simulation.effects._spec import (
    DeviceProfile,
    EffectSpec,
    Params,
    ParamSpec,
    scalar_fit,
)


def intensity_coefficients(transmittance: float) -> tuple[float, float]:
    """``(c_open, c_coding)`` with ``T = c_open·a a + c_coding·φ φ`` (geometric optics)."""
    return (1.0 + transmittance) / 2.0, (1.0 - transmittance) / 2.0


def amplitude_coefficients(transmittance: float) -> tuple[float, float]:
    """``(c_open, c_coding)`` of the amplitude transmittance (for diffraction)."""
    r = math.sqrt(transmittance)
    return (1.0 + r) / 2.0, (1.0 - r) / 2.0


def describe(params: Params, _p: DeviceProfile) -> str:
    """The finding in words."""
    return (
        f"The closed mask cells pass {float(params['transmittance']):.2%} of the light; the "
        "model assumed them opaque."
    )


SPEC = EffectSpec(
    name="mask_leakage",
    stage="kernel",
    description="the opaque mask cells are not fully opaque",
    params={"transmittance": ParamSpec("1", 0.0, (0.0, 1.0), "intensity transmittance of closed cells")},
    kernel=lambda params, _p: {"leakage": params["transmittance"]},
    describe=describe,
    fit=scalar_fit("transmittance", 0.0, 0.03, signed=False),
)
