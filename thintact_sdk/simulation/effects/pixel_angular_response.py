"""``pixel_angular_response``: an extra factor ``cos^p`` of the angle of incidence on the
sensor (microlens / pixel-stack acceptance). It keeps the kernel separable: the radiometric
factor becomes ``cos^(4+p)(theta)/H²``."""

from __future__ import annotations

import math

from thintact_sdk.simulation.effects._spec import (
    DeviceProfile,
    EffectSpec,
    Params,
    ParamSpec,
    scalar_fit,
)


def radiometric_exponent(exponent: float) -> float:
    """The exponent q of ``cos^q(theta)/H²`` with this response (4 for the baseline)."""
    return 4.0 + exponent


def max_angle_deg(p: DeviceProfile) -> float:
    """Angle of incidence (deg) of the steepest ray: scene corner to opposite sensor corner."""
    half_s = 0.5 * math.hypot(p.sensor.rows, p.sensor.cols) * p.sensor.pixel_pitch_um * 1e-3
    half_x = 0.5 * math.hypot(p.scene.rows, p.scene.cols) * p.scene.pixel_pitch_um * 1e-3
    return math.degrees(math.atan((half_s + half_x) / p.geometry.total_mm))


def describe(params: Params, p: DeviceProfile) -> str:
    """The finding in words."""
    e = float(params["exponent"])
    th = max_angle_deg(p)
    drop = 1.0 - math.cos(math.radians(th)) ** e
    return (
        f"The pixels respond less to oblique light than the model assumed: an extra cos^{e:.2f} "
        f"of the angle of incidence, {drop:.0%} less signal at the steepest ray ({th:.0f}°)."
    )


SPEC = EffectSpec(
    name="pixel_angular_response",
    stage="kernel",
    description="pixels are less sensitive to light arriving at an angle (extra cos^p)",
    params={"exponent": ParamSpec("1", 0.0, (0.0, 50.0), "p in cos^p(theta)")},
    kernel=lambda params, _p: {"q": radiometric_exponent(params["exponent"])},
    describe=describe,
    distinguish={"geometry": (
        "a white frame and narrow slits near the edge of the scene: the angular response only "
        "dims, a changed geometry also moves the shadows"
    )},
    fit=scalar_fit("exponent", 0.0, 4.0, signed=False),
)
