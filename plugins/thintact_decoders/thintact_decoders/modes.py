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

import numpy as np

DEFAULT_MODE_RTOL = 1e-3


def kept_mode_counts(sp: np.ndarray, sq: np.ndarray, tau: float, rtol: float) -> tuple[int, int]:
    """``(kp, kq)``: how many leading modes of P and Q have a filter factor ≥ ``rtol``.

    Parameters
    ----------
    sp, sq
        ``C × kP`` and ``C × kQ`` singular values of Pc, Qc per channel, descending (DN units).
    tau
        Tikhonov weight τ (DN²).
    rtol
        Smallest filter factor kept; 0 keeps every mode.

    Returns
    -------
    tuple of int
        The largest count over channels (at least 1 each), so channels stay batched.
    """
    sp2, sq2 = np.atleast_2d(sp) ** 2, np.atleast_2d(sq) ** 2
    if rtol <= 0:
        return sp2.shape[1], sq2.shape[1]
    fp = sp2 * sq2[:, :1] / (sp2 * sq2[:, :1] + tau)  # best factor of each P-mode (at σ_Q,max)
    fq = sq2 * sp2[:, :1] / (sq2 * sp2[:, :1] + tau)
    kp = int(max(np.sum(row >= rtol) for row in fp))
    kq = int(max(np.sum(row >= rtol) for row in fq))
    return max(kp, 1), max(kq, 1)
