"""``sensor_gamma``: ``DN - black = FS·(L/FS)^gamma`` with ``L`` the linear signal in DN and
``FS = saturation_dn - black_level_dn``."""

from __future__ import annotations

import numpy as np

from thintact_sdk.simulation.effects._spec import (
    DeviceProfile,
    EffectSpec,
    Params,
    ParamSpec,
    scalar_fit,
)


def full_scale_dn(profile: DeviceProfile) -> float:
    """``FS = saturation_dn - black_level_dn``."""
    return float(profile.noise.saturation_dn - profile.noise.black_level_dn)


def apply(signal_dn: np.ndarray, gamma: float, full_scale_dn: float) -> np.ndarray:
    """Linear signal in DN above black → response in DN above black (same shape)."""
    if gamma == 1.0:
        return signal_dn
    return full_scale_dn * np.power(np.clip(signal_dn, 0.0, None) / full_scale_dn, gamma)


def _forward(signal_dn: np.ndarray, params: Params, profile: DeviceProfile) -> np.ndarray:
    return apply(signal_dn, params["gamma"], full_scale_dn(profile))


def response(lin_dn: np.ndarray, v: np.ndarray, profile: DeviceProfile) -> tuple[np.ndarray, np.ndarray]:
    """``(h(L), h'(L))`` for the diagnosis's gain solve (L floored at 1e-6·FS so that the
    derivative stays finite)."""
    fs = full_scale_dn(profile)
    g = float(v[0])
    lp = np.maximum(lin_dn, 1e-6 * fs)
    out = fs * (lp / fs) ** g
    return out, g * out / lp


def describe(params: Params, _p: DeviceProfile) -> str:
    """The finding in words."""
    return (
        f"The sensor response is not linear: DN − black = FS·(L/FS)^{float(params['gamma']):.3f}; "
        "the model assumed DN proportional to light."
    )


SPEC = EffectSpec(
    name="sensor_gamma",
    stage="dn",
    order=10,
    description="the sensor's response is a power law of the light instead of linear",
    params={"gamma": ParamSpec("1", 1.0, (0.2, 5.0), "exponent; 1 = linear sensor")},
    forward=_forward,
    describe=describe,
    fit=scalar_fit("gamma", 1.0, 0.05, signed=True, domain="dn", dn_response=response),
)
