"""The T2S gauge: what slit scans cannot determine, and how it is fixed and compared.

``Y = Po X Qoᵀ + Pc X Qcᵀ`` is unchanged by ``[Po Pc] → [Po Pc]·A`` and
``[Qo Qc] → [Qo Qc]·A⁻ᵀ`` for any invertible 2 × 2 ``A`` (acting on the term index). That
covers the scale ambiguity the paper names (``P·a, Q/a``) and a mixing of the open and
coding terms. The decoder needs the open term to be the smooth one (its filter removes
``Po X Qoᵀ`` as the low-frequency part), so:

- mixing: the open pair is the mixture of least roughness (second differences along both
  axes) relative to its size, independently for P and Q; the coding pair is then fixed by
  ``A⁻ᵀ``;
- scale: the paper's rule, ``‖P‖_F = ‖Q‖_F`` for each term (Algorithm 3);
- sign: ``sum(Po) > 0`` and the largest-magnitude entry of ``Pc`` positive.

Comparisons with another set of matrices (e.g. the simulator's two-term fit) use
:func:`operator_error`, which compares the products (gauge-free), and per-term errors after
both sets were put in this gauge.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import eigh

from thintact_sdk.calibration.channel_matrices import ChannelMatrices
from thintact_sdk.reconstruction.t2s import SystemMatrices


def _roughness(a: np.ndarray, b: np.ndarray) -> float:
    """``⟨D a, D b⟩`` with D the second differences along both axes."""
    total = 0.0
    for axis in (0, 1):
        if a.shape[axis] > 2:
            total += float(np.sum(np.diff(a, 2, axis=axis) * np.diff(b, 2, axis=axis)))
    return total


def _smoothest_direction(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Unit 2-vector x minimising roughness(x₀·first + x₁·second) / ‖x₀·first + x₁·second‖²."""
    pair = (first, second)
    rough = np.array([[_roughness(x, y) for y in pair] for x in pair])
    size = np.array([[float(np.sum(x * y)) for y in pair] for x in pair])
    size += np.eye(2) * 1e-12 * max(np.trace(size), 1e-300)
    _, vecs = eigh(rough, size)
    x = vecs[:, 0]
    return x / np.linalg.norm(x)


def balance_frobenius(m: ChannelMatrices) -> ChannelMatrices:
    """Scale each term so that ``‖Po‖_F = ‖Qo‖_F`` and ``‖Pc‖_F = ‖Qc‖_F`` (paper Alg. 3)."""
    out = []
    for p, q in ((m.Po, m.Qo), (m.Pc, m.Qc)):
        npn, nqn = np.linalg.norm(p), np.linalg.norm(q)
        s = np.sqrt(nqn / npn) if npn > 0 and nqn > 0 else 1.0
        out.append((p * s, q / s))
    return ChannelMatrices(out[0][0], out[0][1], out[1][0], out[1][1])


def fix_gauge(m: ChannelMatrices) -> ChannelMatrices:
    """Put ``m`` in the canonical gauge (smooth open term, balanced norms, fixed signs).

    The products ``Po X Qoᵀ + Pc X Qcᵀ`` are unchanged (to rounding).
    """
    a1 = _smoothest_direction(m.Po, m.Pc)
    b1 = _smoothest_direction(m.Qo, m.Qc)
    dot = float(a1 @ b1)
    if abs(dot) < 1e-9:
        return balance_frobenius(m)
    a2 = np.array([-b1[1], b1[0]])  # ⟂ b1
    b2 = np.array([-a1[1], a1[0]])  # ⟂ a1, and a2·b2 = a1·b1
    # A = [a1, a2 / dot] and B = [b1 / dot, b2] satisfy A Bᵀ = I
    a_mat = np.stack([a1, a2 / dot], axis=1)
    b_mat = np.stack([b1 / dot, b2], axis=1)
    po = m.Po * a_mat[0, 0] + m.Pc * a_mat[1, 0]
    pc = m.Po * a_mat[0, 1] + m.Pc * a_mat[1, 1]
    qo = m.Qo * b_mat[0, 0] + m.Qc * b_mat[1, 0]
    qc = m.Qo * b_mat[0, 1] + m.Qc * b_mat[1, 1]
    if po.sum() < 0:
        po, qo = -po, -qo
    flat = pc.ravel()
    if flat.size and flat[np.argmax(np.abs(flat))] < 0:
        pc, qc = -pc, -qc
    return balance_frobenius(ChannelMatrices(po, qo, pc, qc))


def canonical_gauge(sm: SystemMatrices) -> SystemMatrices:
    """``sm`` with every channel in the canonical gauge (:func:`fix_gauge`); same operator.

    A decoder that truncates the open term to a low rank (``t2s-closed-form``) is exact only
    when the open term *is* the smooth, low-rank one: in the gauge the paper's Algorithms 1-3
    land on (or matrices calibrated elsewhere), ``Po`` carries part of the coding term and a
    rank-8 truncation dropped 4 % of its spectrum (docs/calibration.md). Channels whose open
    matrices are all zero (one-term, FlatCam-style) are returned unchanged.
    """
    out = {key: np.array(getattr(sm, key), np.float64) for key in ("Po", "Qo", "Pc", "Qc")}
    for c in range(sm.channels):
        if not (np.any(out["Po"][c]) and np.any(out["Qo"][c])):
            continue
        m = fix_gauge(ChannelMatrices(out["Po"][c], out["Qo"][c], out["Pc"][c], out["Qc"][c]))
        out["Po"][c], out["Qo"][c], out["Pc"][c], out["Qc"][c] = m.Po, m.Qo, m.Pc, m.Qc
    return SystemMatrices(out["Po"], out["Qo"], out["Pc"], out["Qc"])


def _terms(m: ChannelMatrices, sign: float = 1.0) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(sign * m.Po, m.Qo), (sign * m.Pc, m.Qc)]


def _operator_inner(terms_a: list[tuple[np.ndarray, np.ndarray]], terms_b: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """⟨Σ Q_k ⊗ P_k, Σ Q_l ⊗ P_l⟩ = Σ tr(P_kᵀP_l)·tr(Q_kᵀQ_l)."""
    return float(
        sum(np.sum(pa * pb) * np.sum(qa * qb) for pa, qa in terms_a for pb, qb in terms_b)
    )


def operator_error(estimate: ChannelMatrices, reference: ChannelMatrices) -> float:
    """Relative Frobenius error of the linear map ``X ↦ Σ P_k X Q_kᵀ`` (gauge-free).

    Returns ``‖Op_est − Op_ref‖ / ‖Op_ref‖`` where ``Op`` is the ``RS × NM`` matrix of the
    map; computed from ``R × N`` and ``S × M`` traces, never forming ``Op``.
    """
    diff = _terms(estimate) + _terms(reference, -1.0)
    num = _operator_inner(diff, diff)
    den = _operator_inner(_terms(reference), _terms(reference))
    return float(np.sqrt(max(num, 0.0) / den))


def term_errors(estimate: ChannelMatrices, reference: ChannelMatrices) -> dict[str, float]:
    """Relative errors of each matrix after putting both sets in the canonical gauge
    (and the coding pair's sign aligned with the reference).

    Returns ``{"Po": …, "Qo": …, "Pc": …, "Qc": …, "open_term": …, "coding_term": …}``; the
    ``*_term`` entries compare the products ``Q ⊗ P`` of one term (scale-free).
    """
    e, r = fix_gauge(estimate), fix_gauge(reference)
    if float(np.sum(e.Pc * r.Pc)) < 0:  # the coding pair's sign is a convention: align it
        e = type(e)(e.Po, e.Qo, -e.Pc, -e.Qc)
    out: dict[str, float] = {}
    for name in ("Po", "Qo", "Pc", "Qc"):
        x, y = getattr(e, name), getattr(r, name)
        out[name] = float(np.linalg.norm(x - y) / np.linalg.norm(y))
    for label, (pe, qe), (pr, qr) in (("open_term", _terms(e)[0], _terms(r)[0]), ("coding_term", _terms(e)[1], _terms(r)[1])):
        d = [(pe, qe), (-pr, qr)]
        out[label] = float(np.sqrt(max(_operator_inner(d, d), 0.0) / _operator_inner([(pr, qr)], [(pr, qr)])))
    return out
