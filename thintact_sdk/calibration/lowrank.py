"""Low-rank compression of slit measurements, so a calibration never holds every frame.

A slit measurement ``Y`` (``R × S`` DN, one channel) of a separable system has rank 2 (paper
§D: ``Y_hi = p_oi q_oᵀ + p_ci q_cᵀ``); noise and small non-separable effects add a tail of
small singular values. Algorithms 1-3 only ever need products ``Y q`` (``R``) and ``Yᵀ p``
(``S``), so each slit is kept as a rank-``k`` factorisation ``Y ≈ L Rᵀ`` (``L``: ``R × k``,
``Rᵀ``: ``k × S``) plus its exact Frobenius energy: at the paper's size (1024 × 1280, k = 8)
that is 18 KiB per slit and channel instead of 5 MiB in float32.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thintact_sdk.errors import InvalidShapeError

DEFAULT_RANK = 8


@dataclass
class LowRankImage:
    """``Y ≈ left @ right.T`` for one ``R × S`` image.

    Attributes
    ----------
    left
        ``R × k`` float64 (for a fresh compression: left singular vectors × singular values).
    right
        ``S × k`` float64 (for a fresh compression: right singular vectors).
    energy
        ``‖Y‖²_F`` of the full image (DN²), including what the truncation dropped.
    """

    left: np.ndarray
    right: np.ndarray
    energy: float

    @property
    def captured_energy(self) -> float:
        """``‖L Rᵀ‖²_F`` (DN²): the part of :attr:`energy` the rank-k factors keep."""
        return float(np.sum((self.left.T @ self.left) * (self.right.T @ self.right)))

    def dense(self) -> np.ndarray:
        """The rank-k approximation as an ``R × S`` float64 array."""
        return self.left @ self.right.T

    def transposed(self) -> LowRankImage:
        """The factorisation of ``Yᵀ`` (``S × R``): the factors swap roles."""
        return LowRankImage(left=self.right, right=self.left, energy=self.energy)


def compress(image: np.ndarray, rank: int = DEFAULT_RANK, seed: int = 0) -> LowRankImage:
    """Rank-``rank`` factorisation of one ``R × S`` image by a randomised SVD.

    Parameters
    ----------
    image
        ``R × S`` float array (DN above dark).
    rank
        Number of singular triplets kept (≥ 2; the T2S model needs 2).
    seed
        Seed of the random test matrix, so a calibration is reproducible bit for bit.

    Returns
    -------
    LowRankImage
        Factors in float64; two power iterations with 8 oversampling columns make the
        retained triplets accurate to far below the noise of an averaged frame.
    """
    y = np.asarray(image, dtype=np.float64)
    if y.ndim != 2:
        raise InvalidShapeError(f"compress expects an R×S image, got shape {y.shape}")
    r, s = y.shape
    k = max(2, min(rank, r, s))
    width = min(k + 8, r, s)
    omega = np.random.default_rng(seed).standard_normal((s, width))
    basis, _ = np.linalg.qr(y @ omega)
    for _ in range(2):
        basis, _ = np.linalg.qr(y @ (y.T @ basis))
    small = basis.T @ y  # width × S
    u, sv, vt = np.linalg.svd(small, full_matrices=False)
    left = (basis @ u[:, :k]) * sv[None, :k]
    return LowRankImage(left=left, right=vt[:k].T.copy(), energy=float(np.sum(y * y)))
