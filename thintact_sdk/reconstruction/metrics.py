"""Image quality metrics used across the SDK (reconstruction, mask fitness, calibration).

All metrics take images of equal shape (``N × M`` or ``N × M × C``), float arrays in
display units where the peak signal is ``data_range`` (default 1.0).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from thintact_sdk.errors import InvalidShapeError


def psnr(estimate: np.ndarray, truth: np.ndarray, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB: ``10 log10(data_range² / MSE)`` (shapes must match or
    broadcast, e.g. one truth channel against three)."""
    x, y = np.asarray(estimate, np.float64), np.asarray(truth, np.float64)
    try:
        np.broadcast_shapes(x.shape, y.shape)
    except ValueError:
        raise InvalidShapeError(f"psnr: estimate shape {x.shape} does not match truth {y.shape}") from None
    mse = float(np.mean((x - y) ** 2))
    if mse == 0.0:
        return float("inf")
    return 10.0 * np.log10(data_range**2 / mse)


def ssim(estimate: np.ndarray, truth: np.ndarray, data_range: float = 1.0, sigma: float = 1.5) -> float:
    """Structural similarity (Wang et al. 2004) with an 11-tap Gaussian window (σ = 1.5 px).

    Colour images are the mean over channels.
    """
    x = np.asarray(estimate, np.float64)
    y = np.asarray(truth, np.float64)
    if x.shape != y.shape:
        raise InvalidShapeError(f"shape mismatch {x.shape} vs {y.shape}")
    if x.ndim == 3:
        return float(np.mean([ssim(x[..., c], y[..., c], data_range, sigma) for c in range(x.shape[2])]))
    c1 = (0.01 * data_range) ** 2
    c2 = (0.03 * data_range) ** 2

    def f(a: np.ndarray) -> np.ndarray:
        return gaussian_filter(a, sigma, truncate=3.5, mode="reflect")

    mx, my = f(x), f(y)
    sxx = f(x * x) - mx * mx
    syy = f(y * y) - my * my
    sxy = f(x * y) - mx * my
    num = (2 * mx * my + c1) * (2 * sxy + c2)
    den = (mx * mx + my * my + c1) * (sxx + syy + c2)
    return float(np.mean(num / den))
