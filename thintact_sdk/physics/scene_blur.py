"""``scene_blur``: Gaussian blur in the scene plane (diffuser, elastomer scattering).

The blur is integrated over the pixels (see :mod:`thintact_sdk.physics._blur`). Edges are
mirrored (``reflect``), so a uniform scene stays uniform: light scattered out of
the field is balanced by light scattered in from a similarly lit surround.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from thintact_sdk.physics._blur import blur_matrix, blur_pixels
from thintact_sdk.physics._spec import (
    DeviceProfile,
    EffectSpec,
    Params,
    ParamSpec,
    Term,
    scalar_fit,
)


def apply(scenes: np.ndarray, sigma_um: float, pitch_um: float) -> np.ndarray:
    """Blur ``F × N × M × C`` scenes by ``sigma_um`` (scene pixel pitch ``pitch_um``)."""
    if sigma_um <= 0:
        return scenes
    return blur_pixels(scenes, sigma_um / pitch_um, axes=(1, 2))


def _forward(scenes: np.ndarray, params: Params, profile: DeviceProfile) -> np.ndarray:
    return apply(scenes, params["sigma_um"], profile.scene.pixel_pitch_um)


def _terms(params: Params, profile: DeviceProfile) -> Callable[[np.ndarray, np.ndarray], list[Term]]:
    s = params["sigma_um"] / profile.scene.pixel_pitch_um
    g_rows, g_cols = blur_matrix(profile.scene.rows, s), blur_matrix(profile.scene.cols, s)
    return lambda p, q: [(p @ g_rows, q @ g_cols)]


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
