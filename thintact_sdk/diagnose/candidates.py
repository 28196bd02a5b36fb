"""The diagnosis's view of the CONTRACTS §5 effects: how each one is fitted.

Every effect becomes a :class:`Candidate` with a flat vector of fit parameters, its null
value (the effect absent), a typical step (the amplitude used for its first-order
signature), physical bounds, and converters to and from the contract's ``physics``
parameters. ``domain`` says who computes it:

- ``"optical"``: the simulator (``profile.physics``), re-simulating every frame;
- ``"post"``: a linear map of the simulated signal (colour crosstalk, veiling glare),
  applied here without re-simulating;
- ``"dn"``: the digital-number domain after the gain (sensor gamma, saturation);
- ``"linear"``: additive terms fitted in closed form next to the gains (stray light).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from thintact_sdk.profile import Profile

Domain = Literal["optical", "post", "dn", "linear"]
#: polynomial terms of the stray-light surface: (power of x, power of y)
STRAY_TERMS: tuple[tuple[int, int], ...] = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))
DEFAULT_WAVELENGTHS_NM = (625.0, 530.0, 465.0)


@dataclass(frozen=True)
class DataSearch:
    """Start values read off the measurement (no first-order signature needed).

    Attributes
    ----------
    starts
        ``(measured DN at the fitted pixels, profile) -> trial vectors`` (null excluded).
    exact
        ``(best trial vector, measured) -> True`` when the data give the value exactly
        (no refinement).
    refine_width
        ``vector -> half-width`` of the parabola that refines the best trial otherwise.
    """

    starts: Callable[[np.ndarray, Profile], list[np.ndarray]]
    exact: Callable[[np.ndarray, np.ndarray], bool]
    refine_width: Callable[[np.ndarray], float]


@dataclass(frozen=True)
class Proxy:
    """An effect too expensive to score that another effect's fit can stand in for.

    Attributes
    ----------
    source
        Name of the effect whose fit (in the same round) points at this one.
    start
        ``(source's fitted vector, profile) -> start vector or None`` (None: the source
        fit does not point at this effect).
    widths
        Relative half-widths of the parabolas that refine the start, in turn.
    """

    source: str
    start: Callable[[np.ndarray, Profile], np.ndarray | None]
    widths: tuple[float, ...] = (0.02, 0.004)


@dataclass(frozen=True)
class Candidate:
    """One effect as the diagnosis fits it.

    Attributes
    ----------
    name
        CONTRACTS §5 effect name.
    domain
        Who computes it (module docstring).
    labels
        Names of the flat fit parameters, with units.
    null, step, lower, upper
        Functions of the profile giving ``(k,)`` vectors: the null value (effect absent),
        the typical amplitude of the first-order signature, and physical bounds.
    slow_params
        Parameters that switch the simulator to its slow (non-separable) path: left at
        their null value in the score and refined last, time permitting.
    channelwise
        Parameter i acts only on channel i (diffraction wavelengths), so one simulation
        with every parameter stepped gives every column of the Jacobian.
    costly
        Every simulation rebuilds an expensive kernel (the rotated mask's): its full fit may
        use all the time left rather than a share of it.
    joint_refit
        Its values may move when a later effect is fitted (False: kept where accepted).
    search
        Scored by trying values read off the data instead of by a first-order signature.
    proxy
        Not scored itself: started from another effect's fit (when that fit points at it).
    """

    name: str
    domain: Domain
    labels: tuple[str, ...]
    null: Callable[[Profile], np.ndarray]
    step: Callable[[Profile], np.ndarray]
    lower: Callable[[Profile], np.ndarray]
    upper: Callable[[Profile], np.ndarray]
    to_params: Callable[[np.ndarray, Profile], dict[str, Any]]
    from_params: Callable[[dict[str, Any], Profile], np.ndarray]
    channelwise: bool = False
    signed: tuple[bool, ...] = field(default=())
    slow_params: tuple[int, ...] = ()
    costly: bool = False
    joint_refit: bool = True
    search: DataSearch | None = None
    proxy: Proxy | None = None

    @property
    def k(self) -> int:
        return len(self.labels)


def _const(*v: float) -> Callable[[Profile], np.ndarray]:
    arr = np.asarray(v, np.float64)
    return lambda _p: arr.copy()


def _scalar(name: str, key: str) -> tuple[Callable[..., dict[str, Any]], Callable[..., np.ndarray]]:
    def to(v: np.ndarray, _p: Profile) -> dict[str, Any]:
        return {key: round(float(v[0]), 6)}

    def frm(d: dict[str, Any], _p: Profile) -> np.ndarray:
        return np.array([float(d[key])])

    return to, frm


def _wl_to(v: np.ndarray, _p: Profile) -> dict[str, Any]:
    return {"wavelength_nm": [round(float(x), 2) for x in v]}


def _wl_from(d: dict[str, Any], _p: Profile) -> np.ndarray:
    wl = d["wavelength_nm"]
    return np.asarray(wl if isinstance(wl, list) else [wl] * 3, np.float64)


def _mis_to(v: np.ndarray, _p: Profile) -> dict[str, Any]:
    return {"angle_deg": round(float(v[0]), 5), "dx_um": round(float(v[1]), 4), "dy_um": round(float(v[2]), 4)}


def _mis_from(d: dict[str, Any], _p: Profile) -> np.ndarray:
    return np.array([float(d.get("angle_deg", 0.0)), float(d.get("dx_um", 0.0)), float(d.get("dy_um", 0.0))])


def _geo_null(p: Profile) -> np.ndarray:
    return np.array([p.geometry.scene_to_mask_mm, p.geometry.mask_to_sensor_mm])


def _geo_to(v: np.ndarray, _p: Profile) -> dict[str, Any]:
    return {"scene_to_mask_mm": round(float(v[0]), 5), "mask_to_sensor_mm": round(float(v[1]), 5)}


def _geo_from(d: dict[str, Any], p: Profile) -> np.ndarray:
    return np.array(
        [
            float(d.get("scene_to_mask_mm", p.geometry.scene_to_mask_mm)),
            float(d.get("mask_to_sensor_mm", p.geometry.mask_to_sensor_mm)),
        ]
    )


_XT_IDX = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))


def crosstalk_matrix(v: np.ndarray) -> np.ndarray:
    """3×3 colour-crosstalk matrix with unit diagonal from its six off-diagonal terms."""
    m = np.eye(3)
    for (i, j), x in zip(_XT_IDX, v, strict=True):
        m[i, j] = x
    return m


def _xt_to(v: np.ndarray, _p: Profile) -> dict[str, Any]:
    return {"matrix": [[round(float(x), 6) for x in row] for row in crosstalk_matrix(v)]}


def _xt_from(d: dict[str, Any], _p: Profile) -> np.ndarray:
    m = np.asarray(d["matrix"], np.float64)
    return np.array([m[i, j] for i, j in _XT_IDX])


def _sat_null(p: Profile) -> np.ndarray:
    return np.array([p.noise.saturation_dn])


def _sat_lower(p: Profile) -> np.ndarray:
    return np.array([p.noise.black_level_dn + 1.0])


def _stray_to(v: np.ndarray, _p: Profile) -> dict[str, Any]:
    c = np.asarray(v, np.float64).reshape(-1, len(STRAY_TERMS))
    return {
        "mean_dn": [round(float(x), 3) for x in c[:, 0]],
        "polynomial_dn": [[round(float(x), 4) for x in row] for row in c],
        "polynomial_terms": ["1", "x", "y", "x^2", "xy", "y^2"],
        "coordinates": "x, y in units of the sensor half-width/half-height",
    }


def _stray_from(d: dict[str, Any], _p: Profile) -> np.ndarray:
    if "polynomial_dn" in d:
        return np.asarray(d["polynomial_dn"], np.float64).ravel()
    c = np.zeros((3, len(STRAY_TERMS)))
    c[:, 0] = np.asarray(d.get("mean_dn", [0.0, 0.0, 0.0]), np.float64)
    return c.ravel()


def _refraction_from_geometry(geometry_fit: np.ndarray, p: Profile) -> np.ndarray | None:
    """Near the axis refraction acts like a shorter scene gap (z/n at the same d): when the
    geometry fit shortens z/d, start refraction at n = (z/d)_profile / (z/d)_fit."""
    ratio0 = p.geometry.scene_to_mask_mm / p.geometry.mask_to_sensor_mm
    ratio = float(geometry_fit[0] / geometry_fit[1])
    if ratio > 0.995 * ratio0:
        return None
    return np.array([ratio0 / ratio])


def _clip_levels(measured: np.ndarray, p: Profile) -> list[np.ndarray]:
    """Clip levels to try: the top of the measured histogram (a pile-up of equal values when
    the clip acts after the noise) and high quantiles (when it acts before)."""
    if measured.size == 0:
        return []
    top = float(measured.max())
    levels = {top, *(float(np.quantile(measured, q)) for q in (0.9999, 0.999, 0.997, 0.99))}
    black, sat = p.noise.black_level_dn, p.noise.saturation_dn
    return [np.array([lv]) for lv in sorted(levels) if black + 1.0 < lv < sat - 0.5]


def _clip_is_piled_up(level: np.ndarray, measured: np.ndarray) -> bool:
    """At least 20 pixels pile up at the level, which is the top of the data."""
    top = float(measured.max()) if measured.size else -np.inf
    return bool(level[0] == top and int(np.sum(measured >= top - 0.5)) >= 20)


def _build() -> dict[str, Candidate]:
    inf = np.inf
    cands: list[Candidate] = []
    to, frm = _scalar("pixel_angular_response", "exponent")
    cands.append(
        Candidate("pixel_angular_response", "optical", ("exponent",), _const(0.0), _const(4.0),
                  _const(0.0), _const(50.0), to, frm, signed=(False,))
    )
    cands.append(
        Candidate("diffraction", "optical", ("wavelength_nm R", "wavelength_nm G", "wavelength_nm B"),
                  _const(0.0, 0.0, 0.0), _const(*DEFAULT_WAVELENGTHS_NM), _const(1.0, 1.0, 1.0),
                  _const(2000.0, 2000.0, 2000.0), _wl_to, _wl_from, channelwise=True,
                  signed=(False, False, False))
    )
    to, frm = _scalar("refraction", "n_scene_side")
    cands.append(
        Candidate("refraction", "optical", ("n_scene_side",), _const(1.0), _const(0.4), _const(1.0),
                  _const(3.0), to, frm, signed=(False,),
                  proxy=Proxy("geometry", _refraction_from_geometry))
    )
    cands.append(
        Candidate("mask_misalignment", "optical", ("angle_deg", "dx_um", "dy_um"), _const(0, 0, 0),
                  _const(0.3, 5.0, 5.0), _const(-10.0, -500.0, -500.0), _const(10.0, 500.0, 500.0),
                  _mis_to, _mis_from, signed=(True, True, True), costly=True)
    )
    to, frm = _scalar("mask_leakage", "transmittance")
    cands.append(
        Candidate("mask_leakage", "optical", ("transmittance",), _const(0.0), _const(0.03),
                  _const(0.0), _const(1.0), to, frm, signed=(False,))
    )
    cands.append(
        Candidate("geometry", "optical", ("scene_to_mask_mm", "mask_to_sensor_mm"), _geo_null,
                  _const(0.15, 0.03), _const(0.05, 0.05), _const(100.0, 20.0), _geo_to, _geo_from,
                  signed=(True, True))
    )
    to, frm = _scalar("sensor_blur", "sigma_um")
    cands.append(
        Candidate("sensor_blur", "optical", ("sigma_um",), _const(0.0), _const(8.0), _const(0.0),
                  _const(500.0), to, frm, signed=(False,))
    )
    to, frm = _scalar("scene_blur", "sigma_um")
    cands.append(
        Candidate("scene_blur", "optical", ("sigma_um",), _const(0.0), _const(30.0), _const(0.0),
                  _const(2000.0), to, frm, signed=(False,))
    )
    to, frm = _scalar("display_gamma", "gamma")
    cands.append(
        Candidate("display_gamma", "optical", ("gamma",), _const(1.0), _const(0.15), _const(0.2),
                  _const(5.0), to, frm, signed=(True,))
    )
    cands.append(
        Candidate("color_crosstalk", "post", tuple(f"matrix[{i}][{j}]" for i, j in _XT_IDX),
                  _const(*([0.0] * 6)), _const(*([0.03] * 6)), _const(*([-0.5] * 6)),
                  _const(*([0.5] * 6)), _xt_to, _xt_from, signed=(True,) * 6)
    )
    to, frm = _scalar("veiling_glare", "fraction")
    cands.append(
        Candidate("veiling_glare", "post", ("fraction",), _const(0.0), _const(0.03), _const(0.0),
                  _const(1.0), to, frm, signed=(False,))
    )
    to, frm = _scalar("sensor_gamma", "gamma")
    cands.append(
        Candidate("sensor_gamma", "dn", ("gamma",), _const(1.0), _const(0.05), _const(0.2),
                  _const(5.0), to, frm, signed=(True,))
    )
    to, frm = _scalar("saturation", "level_dn")
    cands.append(
        Candidate("saturation", "dn", ("level_dn",), _sat_null, _const(-100.0), _sat_lower,
                  _sat_null, to, frm, signed=(True,), joint_refit=False,
                  search=DataSearch(_clip_levels, _clip_is_piled_up,
                                    lambda v: max(2.0, 0.002 * float(v[0]))))
    )
    n_stray = 3 * len(STRAY_TERMS)
    cands.append(
        Candidate("stray_light", "linear",
                  tuple(f"{ch} {t}" for ch in "RGB" for t in ("1", "x", "y", "x2", "xy", "y2")),
                  _const(*([0.0] * n_stray)), _const(*([5.0] * n_stray)), _const(*([-inf] * n_stray)),
                  _const(*([inf] * n_stray)), _stray_to, _stray_from, signed=(True,) * n_stray,
                  joint_refit=False)
    )
    return {c.name: c for c in cands}


CANDIDATES: dict[str, Candidate] = _build()
OPTICAL = tuple(n for n, c in CANDIDATES.items() if c.domain == "optical")
