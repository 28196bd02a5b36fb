"""Residual statistics against the imaging noise model (CONTRACTS §6 χ²).

The contract statistics themselves (:class:`FitStats`, :func:`fit_stats`,
:func:`normalised_residual`) are the shared ones of
:mod:`~thintact_sdk.diagnosis.core.residual_stats`, re-exported here for the imaging modules;
this module adds what is special to a recording: the noise model and the saturated pixels.

All arrays are ``F × R × S × C`` (frames, sensor rows, sensor columns, channels) in raw
digital numbers (DN, black level included) unless stated otherwise.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from thintact_sdk.diagnosis.core.residual_stats import FitStats, fit_stats, normalised_residual
from thintact_sdk.formats.profiles import NoiseSpec

__all__ = ["FitStats", "VarianceFn", "default_variance_fn", "fit_stats", "normalised_residual",
           "valid_pixels"]

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
