"""Orthonormal 2-D DCT-II (the transform of the paper's frequency-domain filter unit).

Arrays are ``... × R × S`` (the last two axes are transformed); ``idct2(dct2(y)) == y``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

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


class SeparableDCT:
    """The orthonormal 2-D DCT-II of ``... × R × S`` arrays and its inverse, one object for every
    user of the joint filter.

    Without matrices it is scipy's fast transform (numpy arrays). With ``low_block`` or
    ``to_backend`` it multiplies by DCT matrices: ``fwd(Y) = D_R Y D_Sᵀ``, ``inv(Z) = D_Rᵀ Z D_S``,
    either keeping only the ``low_block`` lowest frequencies (filter training) or on another
    array backend (``to_backend`` puts the matrices there, e.g. torch tensors).

    Parameters
    ----------
    shape
        ``(R, S)``, sensor pixels.
    low_block
        ``(kr, ks)``: keep only these lowest frequencies (``fwd`` gives ``... × kr × ks``).
    to_backend
        Converts the float64 DCT matrices to the array type of the data (and its dtype).
    """

    def __init__(self, shape: tuple[int, int], low_block: tuple[int, int] | None = None,
                 to_backend: Callable[[np.ndarray], Any] | None = None) -> None:
        self.shape = (int(shape[0]), int(shape[1]))
        self.low_block = low_block
        self.by_matrices = low_block is not None or to_backend is not None
        if self.by_matrices:
            kr, ks = low_block if low_block is not None else self.shape
            convert = to_backend or (lambda a: a)
            self.dr = convert(dct_matrix(self.shape[0])[:kr])
            self.ds = convert(dct_matrix(self.shape[1])[:ks])

    def fwd(self, y: Any) -> Any:
        """DCT-II over the last two axes."""
        if not self.by_matrices:
            return dct2(y, workers=-1)
        return self.dr @ y @ self.ds.T

    def inv(self, z: Any) -> Any:
        """The inverse (the adjoint, for a low block)."""
        if not self.by_matrices:
            return idct2(z, workers=-1)
        return self.dr.T @ z @ self.ds
