"""Residual statistics against a noise model (CONTRACTS §6 χ²), for any diagnosis.

Arrays are any matching shape (imaging: ``F × R × S × C`` in DN; tactile:
``P × H × W × 3`` in display units); ``variance`` is the noise variance of
measured − predicted in the square of the same unit, ``valid`` the values that count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class FitStats:
    """Goodness of fit of one prediction.

    Attributes
    ----------
    rms_dn
        Root-mean-square of measured − predicted over valid values (the data's unit: DN for
        imaging, display units for tactile).
    chi2_per_dof
        Mean of (measured − predicted)² / σ² over valid values (CONTRACTS §6).
    noise_rms_dn
        Root of the mean noise variance over the same values (what ``rms_dn`` would be for a
        perfect model).
    n_pixels
        Number of valid values (frames × pixels × channels).
    """

    rms_dn: float
    chi2_per_dof: float
    noise_rms_dn: float
    n_pixels: int


def fit_stats(
    measured_dn: np.ndarray, predicted_dn: np.ndarray, variance_dn2: np.ndarray, valid: np.ndarray
) -> FitStats:
    """Contract statistics of a prediction (see :class:`FitStats`); NaN with ``n_pixels`` 0
    when nothing is valid."""
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
    """z = (measured − predicted) / σ, zero at invalid values (same shape as the inputs)."""
    z = (measured_dn - predicted_dn) / np.sqrt(variance_dn2)
    return np.where(valid, z, 0.0)
