"""Closed-form Tikhonov solution of ``min ||Pc X Qcᵀ − Yc||²_F + τ||X||²_F`` (paper eq. 11-12).

With ``Pc = U_P Σ_P V_Pᵀ`` and ``Qc = U_Q Σ_Q V_Qᵀ``::

    X̂ = V_P [(Σ_P U_Pᵀ Yc U_Q Σ_Q) ./ (σ_P σ_Qᵀ + τ 1 1ᵀ)] V_Qᵀ

Everything but ``Yc`` is precomputed, so a solve is four matrix products and one
element-wise scaling.
"""

from __future__ import annotations

import numpy as np

from thintact_sdk.errors import InvalidValueError


class TikhonovSolver:
    """Precomputed closed-form Tikhonov inverse for one channel.

    Parameters
    ----------
    Pc
        ``R × N`` coding system matrix acting on scene rows.
    Qc
        ``S × M`` coding system matrix acting on scene columns.
    tau
        Regularisation weight τ (same units as ``Pc``²·``Qc``²).
    dtype
        Precision of the precomputed factors (float32 for speed, float64 for reference).
    """

    def __init__(self, Pc: np.ndarray, Qc: np.ndarray, tau: float, dtype: type = np.float64) -> None:  # noqa: N803
        if tau < 0:
            raise InvalidValueError("tau must be >= 0")
        up, sp, vpt = np.linalg.svd(np.asarray(Pc, np.float64), full_matrices=False)
        uq, sq, vqt = np.linalg.svd(np.asarray(Qc, np.float64), full_matrices=False)
        self.tau = float(tau)
        self.left: np.ndarray = (sp[:, None] * up.T).astype(dtype)  # Σ_P U_Pᵀ : k_P × R
        self.right: np.ndarray = (uq * sq[None, :]).astype(dtype)  # U_Q Σ_Q : S × k_Q
        denom = np.outer(sp**2, sq**2) + self.tau
        if np.any(denom == 0):
            raise InvalidValueError("tau = 0 with a singular system matrix: use tau > 0")
        self.inv_denom: np.ndarray = (1.0 / denom).astype(dtype)  # k_P × k_Q
        self.vp: np.ndarray = vpt.T.astype(dtype)  # N × k_P
        self.vqt: np.ndarray = vqt.astype(dtype)  # k_Q × M
        self.singular_values_p = sp
        self.singular_values_q = sq

    def solve(self, yc: np.ndarray) -> np.ndarray:
        """Reconstruct ``N × M`` from the coding component ``yc`` (``R × S``)."""
        core = (self.left @ yc.astype(self.left.dtype, copy=False)) @ self.right
        core *= self.inv_denom
        return self.vp @ core @ self.vqt
