"""Illumination field: a per-channel polynomial gain over the image, chosen by BIC.

The real frame is modelled as ``real[p, y, x, c] = g_c(x, y) · sim[p, y, x, c] + noise`` with
``g_c`` a 2-D polynomial of total order 0..``max_order`` in normalised coordinates (−1..1).
Each order is a linear least-squares fit; χ²/dof uses :func:`thintact_sdk.diagnosis.imaging.stats.fit_stats`
with a constant noise variance, and the order with the lowest BIC (χ² + k ln n) is kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thintact_sdk.diagnosis.core.residual_stats import fit_stats


@dataclass
class IlluminationFit:
    """Result of :func:`fit_illumination_field`.

    Attributes
    ----------
    order
        Polynomial order kept (lowest BIC).
    gain
        ``H × W × 3`` fitted gain field (dimensionless).
    chi2_per_dof
        χ²/dof of each order tried, ``{order: value}``.
    bic
        BIC of each order tried, ``{order: value}``.
    """

    order: int
    gain: np.ndarray
    chi2_per_dof: dict[int, float]
    bic: dict[int, float]


def _basis(height: int, width: int, order: int) -> np.ndarray:
    """``K × H × W`` monomials x^i y^j with i + j ≤ order, x and y in [−1, 1]."""
    y, x = np.meshgrid(np.linspace(-1, 1, height), np.linspace(-1, 1, width), indexing="ij")
    return np.stack([x**i * y ** (d - i) for d in range(order + 1) for i in range(d + 1)])


def fit_illumination_field(
    real: np.ndarray, sim: np.ndarray, noise_sigma: float, max_order: int = 3
) -> IlluminationFit:
    """Fit a per-channel polynomial gain field mapping ``sim`` onto ``real``.

    Parameters
    ----------
    real, sim
        ``P × H × W × 3`` frames in display units [0, 1] (same presses, same grid).
    noise_sigma
        Per-pixel noise standard deviation of ``real``, display units (measured from the data).
    max_order
        Highest polynomial order tried.
    """
    n_frames, height, width, channels = real.shape
    variance = np.full(real.shape, float(noise_sigma) ** 2)
    valid = np.ones(real.shape, dtype=bool)
    best: IlluminationFit | None = None
    chi2: dict[int, float] = {}
    bic: dict[int, float] = {}
    for order in range(max_order + 1):
        basis = _basis(height, width, order)
        gain = np.empty((height, width, channels))
        for c in range(channels):
            design = (basis[:, None] * sim[None, ..., c]).reshape(len(basis), -1).T
            coef, *_ = np.linalg.lstsq(design, real[..., c].reshape(-1), rcond=None)
            gain[..., c] = np.tensordot(coef, basis, axes=1)
        stats = fit_stats(real, gain[None] * sim, variance, valid)
        k = len(basis) * channels
        chi2[order] = stats.chi2_per_dof
        bic[order] = stats.chi2_per_dof * stats.n_pixels + k * np.log(stats.n_pixels)
        if best is None or bic[order] < bic[best.order]:
            best = IlluminationFit(order, gain, chi2, bic)
    assert best is not None
    return best
