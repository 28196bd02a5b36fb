"""``stray_light``: a scene-independent additive signal, smooth across the sensor.

Shape (fixed, documented): a paraboloid bright at the sensor centre and falling to half at
the corners, ``1 - 0.5·(r / r_corner)²``, normalised to mean 1 over the sensor; the
parameter ``mean_dn`` sets its mean per channel in DN (so it is defined in DN and needs the
per-channel gain to be expressed in simulator units).

The diagnosis fits any smooth glow, not only this paraboloid: a quadratic surface per
channel (:data:`SURFACE_TERMS`) solved in closed form next to the gains; its mean is
reported as ``mean_dn``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from thintact_sdk.simulation.effects._spec import (
    DeviceProfile,
    EffectSpec,
    FitSpec,
    Params,
    ParamSpec,
    const,
)

#: polynomial terms of the fitted surface: (power of x, power of y), x and y in [-1, 1]
SURFACE_TERMS: tuple[tuple[int, int], ...] = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))
_N_COEF = 3 * len(SURFACE_TERMS)


def shape(rows: int, cols: int) -> np.ndarray:
    """``R × S`` spatial shape with mean 1 (see module docstring)."""
    y = np.arange(rows) - (rows - 1) / 2
    x = np.arange(cols) - (cols - 1) / 2
    r2 = y[:, None] ** 2 + x[None, :] ** 2
    raw = 1.0 - 0.5 * r2 / max(float(r2.max()), 1e-12)
    return raw / raw.mean()


def apply(signal_dn: np.ndarray, mean_dn: Any) -> np.ndarray:
    """``F × R × S × C`` signal in DN (above black) plus the stray-light glow."""
    m = np.asarray(mean_dn, float)
    if not np.any(m):
        return signal_dn
    c = signal_dn.shape[-1]
    return signal_dn + shape(*signal_dn.shape[1:3])[None, :, :, None] * m[:c]


def _forward(signal_dn: np.ndarray, params: Params, _profile: DeviceProfile) -> np.ndarray:
    return apply(signal_dn, params["mean_dn"])


def surface_basis(rows: int, cols: int) -> np.ndarray:
    """``T × R × S`` polynomial terms of :data:`SURFACE_TERMS` over the sensor."""
    y = np.linspace(-1.0, 1.0, rows)[:, None] * np.ones((1, cols))
    x = np.ones((rows, 1)) * np.linspace(-1.0, 1.0, cols)[None, :]
    return np.stack([x**a * y**b for a, b in SURFACE_TERMS])


def _to_params(v: np.ndarray, _p: DeviceProfile) -> dict[str, Any]:
    c = np.asarray(v, np.float64).reshape(-1, len(SURFACE_TERMS))
    return {
        "mean_dn": [round(float(x), 3) for x in c[:, 0]],
        "polynomial_dn": [[round(float(x), 4) for x in row] for row in c],
        "polynomial_terms": ["1", "x", "y", "x^2", "xy", "y^2"],
        "coordinates": "x, y in units of the sensor half-width/half-height",
    }


def _from_params(d: Params, _p: DeviceProfile) -> np.ndarray:
    if "polynomial_dn" in d:
        return np.asarray(d["polynomial_dn"], np.float64).ravel()
    c = np.zeros((3, len(SURFACE_TERMS)))
    c[:, 0] = np.asarray(d.get("mean_dn", [0.0, 0.0, 0.0]), np.float64)
    return c.ravel()


def _report(coef: np.ndarray, basis: np.ndarray, p: DeviceProfile) -> dict[str, Any]:
    """Parameters from the fitted ``C × T`` coefficients: the surface's mean per channel."""
    out = _to_params(coef.ravel(), p)
    surf = np.tensordot(coef, basis, axes=1)  # C × R × S
    out["mean_dn"] = [round(float(x), 3) for x in surf.mean(axis=(1, 2))]
    return out


def describe(params: Params, _p: DeviceProfile) -> str:
    """The finding in words."""
    means = [float(x) for x in params["mean_dn"]]
    return (
        f"Light that never passed the mask adds a smooth, scene-independent glow of "
        f"{', '.join(f'{x:.1f}' for x in means)} DN (R, G, B) on average; the model had none."
    )


SPEC = EffectSpec(
    name="stray_light",
    stage="dn",
    order=0,
    description="light reaching the sensor without passing the mask adds a smooth glow",
    params={
        "mean_dn": ParamSpec("DN", [0.0, 0.0, 0.0], (0.0, 65535.0),
                             "mean added signal per channel (R, G, B)", shape=(3,))
    },
    forward=_forward,
    describe=describe,
    fit=FitSpec(
        "linear", tuple(f"{ch} {t}" for ch in "RGB" for t in ("1", "x", "y", "x2", "xy", "y2")),
        const(*([0.0] * _N_COEF)), const(*([5.0] * _N_COEF)), _to_params, _from_params,
        # polynomial coefficients in DN, not the mean_dn parameter: any sign, unbounded
        bounds=lambda _p: (np.full(_N_COEF, -np.inf), np.full(_N_COEF, np.inf)),
        signed=(True,) * _N_COEF, joint_refit=False,
        basis=surface_basis, report=_report,
    ),
)
