"""``saturation``: pixels clip at ``level_dn`` (absolute DN, black included), below the
profile's declared ``saturation_dn``."""

from __future__ import annotations

from typing import Any

import numpy as np

from thintact_sdk.simulation.effects._spec import (
    DataSearch,
    DeviceProfile,
    EffectSpec,
    FitSpec,
    Params,
    ParamSpec,
)


def apply(signal_dn: np.ndarray, level_dn: float | None, black_level_dn: float) -> np.ndarray:
    """Clip a signal in DN above black at ``level_dn - black_level_dn``."""
    if level_dn is None:
        return signal_dn
    return np.minimum(signal_dn, level_dn - black_level_dn)


def _forward(signal_dn: np.ndarray, params: Params, profile: DeviceProfile) -> np.ndarray:
    return apply(signal_dn, params["level_dn"], profile.noise.black_level_dn)


def response(lin_dn: np.ndarray, v: np.ndarray, profile: DeviceProfile) -> tuple[np.ndarray, np.ndarray]:
    """``(h(L), h'(L))``: the clip and its derivative (0 where clipped)."""
    lev = float(v[0]) - profile.noise.black_level_dn
    clip = lin_dn >= lev
    return np.where(clip, lev, lin_dn), np.where(clip, 0.0, 1.0)


def clip_levels(measured: np.ndarray, p: DeviceProfile) -> list[np.ndarray]:
    """Clip levels to try: the top of the measured histogram (a pile-up of equal values when
    the clip acts after the noise) and high quantiles (when it acts before)."""
    if measured.size == 0:
        return []
    top = float(measured.max())
    levels = {top, *(float(np.quantile(measured, q)) for q in (0.9999, 0.999, 0.997, 0.99))}
    black, sat = p.noise.black_level_dn, p.noise.saturation_dn
    return [np.array([lv]) for lv in sorted(levels) if black + 1.0 < lv < sat - 0.5]


def piled_up(level: np.ndarray, measured: np.ndarray) -> bool:
    """At least 20 pixels pile up at the level, which is the top of the data: read off exactly."""
    top = float(measured.max()) if measured.size else -np.inf
    return bool(level[0] == top and int(np.sum(measured >= top - 0.5)) >= 20)


def _to_params(v: np.ndarray, _p: DeviceProfile) -> dict[str, Any]:
    return {"level_dn": round(float(v[0]), 6)}


def _from_params(d: Params, p: DeviceProfile) -> np.ndarray:
    lev = d.get("level_dn")
    return np.array([float(p.noise.saturation_dn if lev is None else lev)])


def describe(params: Params, p: DeviceProfile) -> str:
    """The finding in words."""
    return (
        f"Pixels clip at {float(params['level_dn']):.0f} DN, below the declared saturation "
        f"{p.noise.saturation_dn:g} DN; the model let them rise further."
    )


SPEC = EffectSpec(
    name="saturation",
    stage="dn",
    order=20,
    description="pixels stop responding above a level lower than the declared saturation",
    params={"level_dn": ParamSpec("DN", None, (0.0, 1e6), "clip level (absolute DN); None = saturation_dn")},
    forward=_forward,
    describe=describe,
    fit=FitSpec(
        "dn", ("level_dn",), lambda p: np.array([p.noise.saturation_dn]), lambda _p: np.array([-100.0]),
        _to_params, _from_params,
        # a clip between one DN above black and the declared saturation
        bounds=lambda p: (np.array([p.noise.black_level_dn + 1.0]), np.array([p.noise.saturation_dn])),
        signed=(True,), joint_refit=False,
        search=DataSearch(clip_levels, piled_up, lambda v: max(2.0, 0.002 * float(v[0]))),
        dn_response=response,
        clip_level_dn=lambda v, _p: float(v[0]),
    ),
)
