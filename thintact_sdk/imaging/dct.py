"""Orthonormal 2-D DCT-II (the transform of the paper's frequency-domain filter unit).

Arrays are ``... × R × S`` (the last two axes are transformed); ``idct2(dct2(y)) == y``.
"""

from __future__ import annotations

import numpy as np
import scipy.fft


def dct_matrix(n: int, dtype: type = np.float64) -> np.ndarray:
    """``n × n`` orthonormal DCT-II matrix ``D`` so that ``dct(y) = D @ y`` along a column."""
    k = np.arange(n)[:, None]
    i = np.arange(n)[None, :]
    d = np.cos(np.pi * (2 * i + 1) * k / (2 * n)) * np.sqrt(2.0 / n)
    d[0] /= np.sqrt(2.0)
    return d.astype(dtype)


def dct2(y: np.ndarray, workers: int | None = None) -> np.ndarray:
    """Orthonormal 2-D DCT-II over the last two axes."""
    return scipy.fft.dctn(y, type=2, norm="ortho", axes=(-2, -1), workers=workers)


def idct2(z: np.ndarray, workers: int | None = None) -> np.ndarray:
    """Inverse of :func:`dct2` (orthonormal DCT-III) over the last two axes."""
    return scipy.fft.idctn(z, type=2, norm="ortho", axes=(-2, -1), workers=workers)
