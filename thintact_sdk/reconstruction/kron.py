"""Nearest Kronecker product (Van Loan–Pitsianis) of a sum of separable terms.

An operator ``X ↦ Σ_k P_k X Q_kᵀ`` is ``A = Σ_k Q_k ⊗ P_k`` acting on ``vec(X)``. Its best
rank-1 Kronecker approximation ``Q ⊗ P`` in the Frobenius norm is the top singular pair of
the rearranged matrix ``Σ_k vec(P_k) vec(Q_k)ᵀ``; with only K terms this is a K × K
eigenproblem on the Gram matrices of the terms, so the big operator is never formed.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def nearest_kron(terms: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Best ``(P, Q)`` such that ``Q ⊗ P ≈ Σ_k Q_k ⊗ P_k`` (Frobenius norm).

    Parameters
    ----------
    terms
        ``(P_k: R × N, Q_k: S × M)`` pairs.

    Returns
    -------
    P, Q
        ``R × N`` and ``S × M`` float64 with equal Frobenius norms and ``ΣP ≥ 0``.
    """
    if not terms:
        raise ValueError("nearest_kron needs at least one term")
    ps = np.stack([np.asarray(p, np.float64).ravel() for p, _ in terms])  # K × RN
    qs = np.stack([np.asarray(q, np.float64).ravel() for _, q in terms])  # K × SM
    shape_p = np.shape(terms[0][0])
    shape_q = np.shape(terms[0][1])
    gram_p = ps @ ps.T
    gram_q = qs @ qs.T
    evals, evecs = np.linalg.eigh(gram_p)
    keep = evals > evals.max() * 1e-12
    if not np.any(keep):
        return np.zeros(shape_p), np.zeros(shape_q)
    v = evecs[:, keep]
    sqrt_e = np.sqrt(evals[keep])
    # Pm = U_p (diag(sqrt_e) vᵀ) with U_p orthonormal: rearranged matrix = U_p B Qmᵀ, B = diag(sqrt_e) vᵀ
    b = sqrt_e[:, None] * v.T  # r × K
    small = b @ gram_q @ b.T  # r × r, = (B Qmᵀ)(B Qmᵀ)ᵀ
    w, u = np.linalg.eigh(small)
    sigma2, u1 = float(w[-1]), u[:, -1]
    if sigma2 <= 0:
        return np.zeros(shape_p), np.zeros(shape_q)
    sigma = np.sqrt(sigma2)
    coef_p = v @ (u1 / sqrt_e)  # U_p u1 = Pm coef_p (unit norm)
    coef_q = b.T @ u1 / sigma  # right singular vector = Qm coef_q (unit norm)
    p_fit = (coef_p @ ps).reshape(shape_p) * np.sqrt(sigma)
    q_fit = (coef_q @ qs).reshape(shape_q) * np.sqrt(sigma)
    if p_fit.sum() < 0:
        p_fit, q_fit = -p_fit, -q_fit
    return p_fit, q_fit
