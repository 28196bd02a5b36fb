"""Which Tikhonov modes are worth computing.

In the closed-form solve ``X̂ = V_P [(Σ_P U_Pᵀ Y U_Q Σ_Q) ./ (σ_P² σ_Qᵀ² + τ)] V_Qᵀ`` the mode
``(i, j)`` passes the scene coefficient ``x_ij`` with the filter factor
``f_ij = σ_Pi² σ_Qj² / (σ_Pi² σ_Qj² + τ)`` (and the data with the weight
``σ_Pi σ_Qj / (σ_Pi² σ_Qj² + τ)``). A row ``i`` of P-modes whose largest factor (at the
largest σ_Q) is below ``rtol`` carries at most that fraction of any scene coefficient, far
below the noise; dropping it removes rows of the two big products. The same holds for Q.
The PSNR cost of the default is measured in ``docs/reconstruction.md`` (≤ 0.05 dB).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from thintact_sdk.errors import InvalidValueError

DEFAULT_MODE_RTOL = 1e-3

TauSpec = float | Sequence[float] | np.ndarray
"""A Tikhonov weight: one τ for every channel, or one per channel (DN²)."""


def channel_taus(tau: TauSpec, channels: int) -> np.ndarray:
    """τ per channel, ``(channels,)`` float64, from one value or a per-channel sequence.

    Raises
    ------
    InvalidValueError
        A τ that is not a finite number > 0, or a sequence of the wrong length.
    """
    arr = np.atleast_1d(np.asarray(tau, np.float64))
    if arr.ndim != 1 or arr.size not in (1, channels):
        raise InvalidValueError(f"tau must be one value or one per channel ({channels}), got {arr.size}")
    if not np.all(np.isfinite(arr) & (arr > 0)):
        raise InvalidValueError(f"tau must be > 0, got {arr.tolist()}")
    return np.broadcast_to(arr, (channels,)).copy()


def representative_tau(taus: np.ndarray) -> float:
    """One number for a per-channel τ (their geometric mean; the τ itself when they agree)."""
    return float(np.exp(np.mean(np.log(taus))))


def kept_mode_counts(sp: np.ndarray, sq: np.ndarray, tau: float | np.ndarray, rtol: float) -> tuple[int, int]:
    """``(kp, kq)``: how many leading modes of P and Q have a filter factor ≥ ``rtol``.

    Parameters
    ----------
    sp, sq
        ``C × kP`` and ``C × kQ`` singular values of Pc, Qc per channel, descending (DN units).
    tau
        Tikhonov weight τ (DN²), one value or one per channel.
    rtol
        Smallest filter factor kept; 0 keeps every mode.

    Returns
    -------
    tuple of int
        The largest count over channels (at least 1 each), so channels stay batched.
    """
    sp2, sq2 = np.atleast_2d(sp) ** 2, np.atleast_2d(sq) ** 2
    tau = np.asarray(tau, np.float64).reshape(-1, 1)
    if rtol <= 0:
        return sp2.shape[1], sq2.shape[1]
    fp = sp2 * sq2[:, :1] / (sp2 * sq2[:, :1] + tau)  # best factor of each P-mode (at σ_Q,max)
    fq = sq2 * sp2[:, :1] / (sq2 * sp2[:, :1] + tau)
    kp = int(max(np.sum(row >= rtol) for row in fp))
    kq = int(max(np.sum(row >= rtol) for row in fq))
    return max(kp, 1), max(kq, 1)
