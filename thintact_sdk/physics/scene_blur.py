"""``scene_blur``: Gaussian blur in the scene plane (diffuser, elastomer scattering).

The blur is integrated over the pixels (see :mod:`thintact_sdk.physics._blur`). Edges are
mirrored (``reflect``), so a uniform scene stays uniform: light scattered out of
the field is balanced by light scattered in from a similarly lit surround.
"""

from __future__ import annotations

import numpy as np

from thintact_sdk.physics._blur import blur_pixels
from thintact_sdk.physics._spec import EffectSpec, ParamSpec

SPEC = EffectSpec(
    name="scene_blur",
    stage="scene",
    description="the scene is seen through a scattering layer that blurs it (Gaussian)",
    params={"sigma_um": ParamSpec("um", 0.0, (0.0, 5000.0), "standard deviation in the scene plane")},
)


def apply(scenes: np.ndarray, sigma_um: float, pitch_um: float) -> np.ndarray:
    """Blur ``F × N × M × C`` scenes by ``sigma_um`` (scene pixel pitch ``pitch_um``)."""
    if sigma_um <= 0:
        return scenes
    return blur_pixels(scenes, sigma_um / pitch_um, axes=(1, 2))
