"""``veiling_glare``: each channel gains ``fraction`` × (that frame's mean signal in it)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from thintact_sdk.simulation.effects._spec import (
    DeviceProfile,
    EffectSpec,
    Params,
    ParamSpec,
    Term,
    scalar_fit,
)


def apply(signal: np.ndarray, fraction: float) -> np.ndarray:
    """``F × R × S × C`` → same, plus ``fraction·mean`` over rows and columns per frame/channel."""
    if fraction == 0:
        return signal
    return signal + fraction * signal.mean(axis=(1, 2), keepdims=True)


def _forward(signal: np.ndarray, params: Params, _profile: DeviceProfile) -> np.ndarray:
    return apply(signal, float(params["fraction"]))


def _terms(params: Params, _profile: DeviceProfile) -> Callable[[np.ndarray, np.ndarray], list[Term]]:
    """Each term ``(P, Q)`` gains its frame-mean term ``(f/R·1 P, 1/S·1 Q)``."""
    fraction = float(params["fraction"])

    def split(p: np.ndarray, q: np.ndarray) -> list[Term]:
        if not fraction:
            return [(p, q)]
        r, s = p.shape[0], q.shape[0]
        return [(p, q), (fraction / r * np.ones((r, r)) @ p, 1.0 / s * np.ones((s, s)) @ q)]

    return split


def describe(params: Params, _p: DeviceProfile) -> str:
    """The finding in words."""
    return (
        f"A uniform veil adds {float(params['fraction']):.2%} of each frame's mean signal to "
        "every pixel (glare inside the sensor stack); the model had no such veil."
    )


SPEC = EffectSpec(
    name="veiling_glare",
    stage="signal",
    order=20,
    description="scattered light adds a uniform veil proportional to the frame's mean brightness",
    params={"fraction": ParamSpec("1", 0.0, (0.0, 1.0), "veil / frame mean, per channel")},
    forward=_forward,
    separable_terms=_terms,
    describe=describe,
    distinguish={"stray_light": (
        "a dark frame and a bright frame: glare scales with the frame's mean signal, stray light "
        "does not"
    )},
    fit=scalar_fit("fraction", 0.0, 0.03, signed=False, domain="post"),
    reads_beyond_pixel="a share of the whole frame's mean signal",
)
