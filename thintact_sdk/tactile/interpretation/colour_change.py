"""The photometric-stereo feature: a frame's colour change from the no-contact background, with
marker pixels filled from their neighbours (shared by the interpreter and LUT calibration)."""

from __future__ import annotations

import cv2
import numpy as np


def fill_masked(values: np.ndarray, mask: np.ndarray, sigma_px: float) -> np.ndarray:
    """Replace masked pixels by the Gaussian-weighted mean of unmasked neighbours.

    The narrowest Gaussian that reaches enough unmasked neighbours is used: ``sigma_px``
    first, then 3× and 9× as wide where a hole is too big for it.

    Parameters
    ----------
    values
        ``N × M`` or ``N × M × C`` float array.
    mask
        ``N × M`` bool, True where ``values`` is not to be trusted.
    sigma_px
        Gaussian width in pixels (about a third of a marker's diameter).
    """
    if not mask.any():
        return values
    keep = (~mask).astype(np.float32)
    v = np.ascontiguousarray(values, np.float32)
    out = v.copy()
    todo = mask.copy()
    for scale in (1.0, 3.0, 9.0):
        sigma = sigma_px * scale
        num = cv2.GaussianBlur(v * (keep[..., None] if v.ndim == 3 else keep), (0, 0), sigma)
        den = cv2.GaussianBlur(keep, (0, 0), sigma)
        ok = todo & (den > 0.02) if scale < 9.0 else todo
        filled = num / np.maximum(den, 1e-6)[..., None] if v.ndim == 3 else num / np.maximum(
            den, 1e-6)
        out[ok] = filled[ok]
        todo &= ~ok
        if not todo.any():
            break
    return out


def colour_change(
    image: np.ndarray,
    background: np.ndarray,
    marker_mask: np.ndarray | None,
    marker_sigma_px: float,
    smooth_px: float,
) -> np.ndarray:
    """The photometric-stereo feature: image minus background, marker pixels filled from
    their neighbours, then a light Gaussian (``smooth_px``) against reconstruction noise.

    Returns
    -------
    numpy.ndarray
        ``N × M × 3`` float32 colour change (display units).
    """
    change = np.asarray(image, np.float32) - background
    if marker_mask is not None and marker_mask.any():
        change = fill_masked(change, marker_mask, marker_sigma_px)
    if smooth_px > 0:
        change = cv2.GaussianBlur(np.ascontiguousarray(change), (0, 0), smooth_px)
    return change
