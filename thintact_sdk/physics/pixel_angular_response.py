"""``pixel_angular_response``: an extra factor ``cos^p`` of the angle of incidence on the
sensor (microlens / pixel-stack acceptance). It keeps the kernel separable: the radiometric
factor becomes ``cos^(4+p)(theta)/H²``."""

from __future__ import annotations

from thintact_sdk.physics._spec import EffectSpec, ParamSpec

SPEC = EffectSpec(
    name="pixel_angular_response",
    stage="kernel",
    description="pixels are less sensitive to light arriving at an angle (extra cos^p)",
    params={"exponent": ParamSpec("1", 0.0, (0.0, 50.0), "p in cos^p(theta)")},
)


def radiometric_exponent(exponent: float) -> float:
    """The exponent q of ``cos^q(theta)/H²`` with this response (4 for the baseline)."""
    return 4.0 + exponent
