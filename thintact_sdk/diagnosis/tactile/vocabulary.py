"""The tactile effect vocabulary: what the SDK's tactile simulation leaves out, each as a term
of the forward model (:mod:`.model`) that can be switched on and fitted.

| name | parameters | meaning |
|---|---|---|
| ``illumination_field`` | ``order``, per-channel ``gain_range`` | LED fall-off / non-uniform light: a polynomial gain over the image (order by BIC) |
| ``background_texture`` | ``strength`` per channel, ``texture_rms`` | the gel's printed/moulded texture and fixed pattern, read from the no-contact frame |
| ``exposure_drift`` | ``rms`` per channel | each frame has its own gain (LED current, auto exposure) |
| ``led_directions`` | per channel ``azimuth_deg``, ``elevation_deg``, ``ambient`` | the lights are not the SDK's 10-LED layout: one fitted Lambertian light per channel |
| ``specular_lobe`` | ``shininess``, ``strength`` per channel | a Phong lobe around each channel's light (non-Lambertian gel) |
| ``colour_crosstalk`` | ``matrix`` 3×3, diagonal 1 | channels see each other's shading (filters, LED spectra) |
| ``elastomer_blur`` | ``sigma_mm`` | the gel smooths the indenter by a Gaussian of another width than the profile's |
| ``optical_spread`` | ``sigma_mm`` | light scattered in the gel spreads the shading (not the surface) by a Gaussian |
| ``gel_sink_in`` | ``skirt_mm`` | the gel sinks in around the contact: a skirt ``∝ K₀(r/L)`` outside the ball's contact circle (a thin layer on glass) |
| ``camera_gamma`` | ``gamma`` | the camera's response is a power law, not linear |

Not in the vocabulary (flagged as unexplained when they leave structure): shadowing by the
indenter, gel thickness variation, a spatially varying blur.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from thintact_sdk.diagnosis.tactile.fit import (
    MAX_FIELD_ORDER,
    PressData,
    all_normals,
    fit_linear,
    scan_scalar,
    score,
)
from thintact_sdk.diagnosis.tactile.press_model import Normals, Press, TactileModel

VOCABULARY = ("illumination_field", "background_texture", "exposure_drift", "led_directions",
              "specular_lobe", "colour_crosstalk", "elastomer_blur", "optical_spread", "gel_sink_in", "camera_gamma")


OPT_IN = ("gel_sink_in",)
"""Effects tried only when asked for (``diagnose-tactile --effects``): on the Taxim GelSight
pack the greedy selection takes ``gel_sink_in`` early and ends at a worse final fit
(χ²/dof 2.13 against 1.80 without it; docs/tactile.md)."""
DEFAULT_EFFECTS = tuple(n for n in VOCABULARY if n not in OPT_IN)


def _with(model: TactileModel, name: str) -> TactileModel:
    m = model.copy()
    m.effects.append(name)
    return m


def _field(model: TactileModel, data: PressData, presses: list[Press],
           normals: list[Normals]) -> TactileModel | None:
    best: tuple[float, TactileModel] | None = None
    for order in range(1, MAX_FIELD_ORDER + 1):
        m = _with(model, "illumination_field")
        k = (order + 1) * (order + 2) // 2
        m.field_coef = np.concatenate([model.field_coef[:, :1],
                                       np.zeros((3, k - 1))], axis=1)
        m = fit_linear(m, data, normals)
        bic = score(m, data, normals)[0].bic  # n_params counts the field's coefficients
        if best is None or bic < best[0]:
            best = (bic, m)
    return None if best is None else best[1]


def _linear_effect(name: str) -> Callable[..., TactileModel | None]:
    def propose(model: TactileModel, data: PressData, presses: list[Press],
                normals: list[Normals]) -> TactileModel | None:
        m = _with(model, name)
        if name == "led_directions":
            m.light = np.zeros((3, 3))
        return fit_linear(m, data, normals, iterations=5)
    return propose


def _scanned_effect(name: str, attr: str, grid: list[float], needs_light: bool = False,
                    reshades: bool = False) -> Callable[..., TactileModel | None]:
    """A proposer for an effect with one nonlinear scalar (``attr``): each grid value is set,
    the linear terms refitted, and the value with the lowest BIC kept (refined by
    :func:`scan_scalar`). ``needs_light``: only once a light is fitted; ``reshades``: the
    scalar changes the press normals (a blur width), which are recomputed per value."""
    def propose(model: TactileModel, data: PressData, presses: list[Press],
                normals: list[Normals]) -> TactileModel | None:
        if needs_light and model.light is None:
            return None
        fits: dict[float, TactileModel] = {}

        def cost(value: float) -> float:
            m = _with(model, name)
            setattr(m, attr, float(value))
            nrm = all_normals(data, presses, m.sigma_mm, m.skirt_mm) if reshades else normals
            m = fit_linear(m, data, nrm, iterations=3)
            fits[float(value)] = m
            return score(m, data, nrm)[0].bic

        best, _ = scan_scalar(cost, grid)
        return fits[best]
    return propose


def _crosstalk(model: TactileModel, data: PressData, presses: list[Press],
               normals: list[Normals]) -> TactileModel | None:
    if model.light is not None:
        return None  # a mix of directional lights is one directional light: not identifiable
    return _linear_effect("colour_crosstalk")(model, data, presses, normals)


PROPOSERS: dict[str, Callable[..., TactileModel | None]] = {
    "illumination_field": _field,
    "background_texture": _linear_effect("background_texture"),
    "exposure_drift": _linear_effect("exposure_drift"),
    "led_directions": _linear_effect("led_directions"),
    "specular_lobe": _scanned_effect("specular_lobe", "shininess", [2.0, 5.0, 12.0, 30.0], needs_light=True),
    "colour_crosstalk": _crosstalk,
    "elastomer_blur": _scanned_effect("elastomer_blur", "sigma_mm", [0.1, 0.3, 0.6, 1.0, 1.5], reshades=True),
    "optical_spread": _scanned_effect("optical_spread", "spread_mm", [0.1, 0.3, 0.6, 1.0, 1.5]),
    "gel_sink_in": _scanned_effect("gel_sink_in", "skirt_mm", [0.2, 0.4, 0.8, 1.2, 1.8], reshades=True),
    "camera_gamma": _scanned_effect("camera_gamma", "gamma", [0.3, 0.45, 0.7, 1.0, 1.5]),
}


def effect_params(name: str, model: TactileModel, mm_per_px: float) -> dict[str, object]:
    """The fitted parameters of effect ``name`` in ``model``, JSON-ready, in the units of the
    vocabulary table."""
    r = lambda v, n=4: float(round(float(v), n))  # noqa: E731
    if name == "illumination_field":
        from thintact_sdk.diagnosis.tactile.press_model import polynomial_basis

        k = model.field_coef.shape[1]
        f = np.einsum("ck,khw->hwc", model.field_coef, polynomial_basis(60, 80, model.field_order)[:k])
        centre = f[30, 40]
        return {"order": model.field_order,
                "gain_min": [r(v) for v in f.min(axis=(0, 1)) / centre],
                "gain_max": [r(v) for v in f.max(axis=(0, 1)) / centre]}
    if name == "background_texture":
        return {"strength": [r(v) for v in model.texture_strength]}
    if name == "exposure_drift":
        e = np.ones((1, 3)) if model.exposure is None else model.exposure
        return {"rms": [r(v) for v in e.std(axis=0)]}
    if name == "led_directions":
        assert model.light is not None
        out: dict[str, object] = {}
        for c, ch in enumerate("RGB"):
            u, v, w = model.light[c]
            out[ch] = {"azimuth_deg": r(np.degrees(np.arctan2(v, u)), 1),
                       "elevation_deg": r(np.degrees(np.arctan2(w, np.hypot(u, v))), 1),
                       "ambient": r(1.0 - w, 3), "vector": [r(u), r(v), r(w)]}
        return out
    if name == "specular_lobe":
        return {"shininess": r(model.shininess, 2), "strength": [r(v) for v in model.specular]}
    if name == "colour_crosstalk":
        return {"matrix": [[r(v) for v in row] for row in model.crosstalk]}
    if name == "elastomer_blur":
        return {"sigma_mm": r(model.sigma_mm)}
    if name == "optical_spread":
        return {"sigma_mm": r(model.spread_mm)}
    if name == "gel_sink_in":
        return {"skirt_mm": r(model.skirt_mm)}
    if name == "camera_gamma":
        return {"gamma": r(model.gamma)}
    raise KeyError(name)
