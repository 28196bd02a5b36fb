"""Residual statistics against the noise model (CONTRACTS §6 χ²).

All arrays are ``F × R × S × C`` (frames, sensor rows, sensor columns, channels) in raw
digital numbers (DN, black level included) unless stated otherwise.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from thintact_sdk.formats.profiles import NoiseSpec

VarianceFn = Callable[[np.ndarray, NoiseSpec], np.ndarray]


def default_variance_fn() -> VarianceFn:
    """The project's noise model: ``thintact_sdk.simulation.noise.noise_variance_dn``."""
    from thintact_sdk.simulation.noise import noise_variance_dn

    return noise_variance_dn


def valid_pixels(
    measured_dn: np.ndarray,
    predicted_dn: np.ndarray,
    noise: NoiseSpec,
    level_dn: float | None = None,
    exclude: np.ndarray | None = None,
) -> np.ndarray:
    """Boolean mask of unsaturated pixels (the pixels χ² is taken over).

    A pixel is saturated when its measurement reaches the declared ``saturation_dn``
    (within half a DN) or its prediction does; with a fitted clip ``level_dn`` below that,
    pixels where both measurement and prediction reach the level are saturated too.

    Parameters
    ----------
    exclude
        Optional ``R × S`` boolean mask of sensor pixels to leave out (e.g. defects).
    """
    sat = float(noise.saturation_dn)
    ok = (measured_dn < sat - 0.5) & (predicted_dn < sat - 0.5)
    if level_dn is not None and level_dn < sat:
        ok &= ~((measured_dn >= level_dn - 0.5) & (predicted_dn >= level_dn - 0.5))
    if exclude is not None:
        ok &= ~exclude[None, :, :, None]
    return ok


@dataclass
class FitStats:
    """Goodness of fit of one prediction.

    Attributes
    ----------
    rms_dn
        Root-mean-square of measured − predicted over valid pixels, DN.
    chi2_per_dof
        Mean of (measured − predicted)² / σ² over valid pixels, σ² from the noise model at
        the predicted value (CONTRACTS §6).
    noise_rms_dn
        Root of the mean noise variance over the same pixels, DN (what ``rms_dn`` would be
        for a perfect model).
    n_pixels
        Number of valid pixel values (frames × pixels × channels).
    """

    rms_dn: float
    chi2_per_dof: float
    noise_rms_dn: float
    n_pixels: int


def fit_stats(
    measured_dn: np.ndarray, predicted_dn: np.ndarray, variance_dn2: np.ndarray, valid: np.ndarray
) -> FitStats:
    """Contract statistics of a prediction (see :class:`FitStats`)."""
    r = (measured_dn - predicted_dn)[valid]
    v = variance_dn2[valid]
    n = int(r.size)
    if n == 0:
        return FitStats(float("nan"), float("nan"), float("nan"), 0)
    return FitStats(
        rms_dn=float(np.sqrt(np.mean(r * r))),
        chi2_per_dof=float(np.mean(r * r / v)),
        noise_rms_dn=float(np.sqrt(np.mean(v))),
        n_pixels=n,
    )


def normalised_residual(
    measured_dn: np.ndarray, predicted_dn: np.ndarray, variance_dn2: np.ndarray, valid: np.ndarray
) -> np.ndarray:
    """z = (measured − predicted) / σ, zero at invalid pixels (``F × R × S × C``)."""
    z = (measured_dn - predicted_dn) / np.sqrt(variance_dn2)
    return np.where(valid, z, 0.0)
