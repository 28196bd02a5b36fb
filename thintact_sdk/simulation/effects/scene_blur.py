"""``scene_blur``: Gaussian blur in the scene plane (diffuser, elastomer scattering).

The blur is integrated over the pixels (see :mod:`thintact_sdk.simulation.effects._blur`). Edges are
mirrored (``reflect``), so a uniform scene stays uniform: light scattered out of
the field is balanced by light scattered in from a similarly lit surround.
"""

from __future__ import annotations

import numpy as np

from thintact_sdk.simulation.effects._blur import blur_by_um, plane_blur_hooks
from thintact_sdk.simulation.effects._spec import (
    DeviceProfile,
    EffectSpec,
    Params,
    ParamSpec,
    scalar_fit,
)


def apply(scenes: np.ndarray, sigma_um: float, pitch_um: float) -> np.ndarray:
    """Blur ``F × rows × cols × C`` scenes by ``sigma_um`` (scene pixel pitch ``pitch_um``)."""
    return blur_by_um(scenes, sigma_um, pitch_um)


_forward, _terms = plane_blur_hooks("scene")


def describe(params: Params, p: DeviceProfile) -> str:
    """The finding in words."""
    s = float(params["sigma_um"])
    return (
        f"The scene is blurred before it reaches the mask: a Gaussian of σ = {s:.1f} um "
        f"({s / p.scene.pixel_pitch_um:.2f} scene pixels), e.g. a diffuser or scattering in the "
        "elastomer; the model assumed sharp scene pixels."
    )


SPEC = EffectSpec(
    name="scene_blur",
    stage="scene",
    order=10,
    description="the scene is seen through a scattering layer that blurs it (Gaussian)",
    params={"sigma_um": ParamSpec("um", 0.0, (0.0, 5000.0), "standard deviation in the scene plane")},
    forward=_forward,
    separable_terms=_terms,
    describe=describe,
    distinguish={
        "sensor_blur": (
            "fine slits and checkers at several scales: scene blur softens the scene, sensor blur "
            "the mask's shadow, which stays sharp for a white scene under scene blur"
        ),
        "diffraction": (
            "a white frame: diffraction still softens the mask's shadow, scene blur leaves it "
            "unchanged"
        ),
    },
    fit=scalar_fit("sigma_um", 0.0, 30.0, signed=False),
)
