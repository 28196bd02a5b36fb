"""Separable simulator kernel: ``Y_c = Σ_k P_k X_c Q_kᵀ`` (rows along y, columns along x).

The transmittance of a separable mask inside its K×K area is
``T = ½·a(m_x)a(m_y) + ½·φ(m_x)φ_rows(m_y)`` (``a`` the aperture indicator, ``φ`` the ±1
cell values, both zero outside the mask), and the radiometric factor is expanded as
``Σ_l f_l(dx)·g_l(dy)`` (:mod:`thintact_sdk.simulation.radiometry`). Each product of an
x-profile with an x-factor and a y-profile with a y-factor is one separable term. Along each
axis the double box integral (sensor pixel × scene pixel) of the mask profile is exact
(:mod:`thintact_sdk.simulation.axis`); the smooth factor enters through its value and its
first and second derivatives at each pixel pair's centre offset (a Taylor expansion), with
the moments of the box integral taken from ``n_sub × n_sub`` sub-rectangles (third-order
error, ~(pair size / H)³).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from thintact_sdk.simulation.axis import AxisGrid, box_box_integrals


@dataclass
class SeparableTerm:
    """One term ``P X Qᵀ``: ``P`` is ``R × N`` (rows, y), ``Q`` is ``S × M`` (columns, x).

    ``part`` is ``"open"`` (from the all-open half of the mask) or ``"coding"``.
    """

    P: np.ndarray  # noqa: N815 - the paper's symbols
    Q: np.ndarray  # noqa: N815
    part: str


@dataclass
class SeparableKernel:
    """The terms of every channel (channels may share one list)."""

    terms: list[list[SeparableTerm]]
    info: dict[str, float] = field(default_factory=dict)
    _plans: dict[tuple[int, str], _Plan] = field(default_factory=dict)

    def plan(self, channel: int, dtype: str = "float64") -> _Plan:
        """How a channel's terms are applied: smooth terms (numerically low-rank ``P`` and
        ``Q``, e.g. the open half when the aperture edge is out of view) through their
        truncated SVDs, the others stacked for one GEMM per frame batch."""
        key = (id(self.terms[channel]), dtype)
        if key not in self._plans:
            self._plans[key] = _Plan.build(self.terms[channel], dtype)
        return self._plans[key]

    def apply(self, scenes: np.ndarray, dtype: str = "float64") -> np.ndarray:
        """``F × N × M × C`` scenes → ``F × R × S × C`` float64 signal (simulator units);
        ``dtype`` is the arithmetic precision (``"float32"``: about 2× faster, ~1e-7)."""
        f, n, m, c = scenes.shape
        out: np.ndarray | None = None
        groups: dict[int, list[int]] = {}
        for ch in range(c):
            groups.setdefault(id(self.terms[ch]), []).append(ch)
        for chans in groups.values():
            x = np.ascontiguousarray(scenes[..., chans].transpose(0, 3, 1, 2), dtype=dtype)
            y = self.plan(chans[0], dtype).apply(x.reshape(-1, n, m))
            r, s = y.shape[1:]
            if out is None:
                out = np.empty((f, r, s, c))
            out[..., chans] = y.reshape(f, len(chans), r, s).transpose(0, 2, 3, 1)
        assert out is not None
        return out


LOW_RANK_TOL = 1e-10
"""Relative singular-value cut for applying a smooth term through its truncated SVD."""


@dataclass
class _Plan:
    p_cat: np.ndarray | None  # (R, K·N) dense terms
    q_cat: np.ndarray | None  # (K·S, M)
    k_dense: int
    low_rank: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]  # Up, Bp, Uq, Bq
    rows: int
    cols: int

    @classmethod
    def build(cls, terms: list[SeparableTerm], dtype: str) -> _Plan:
        dense: list[SeparableTerm] = []
        low: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        for t in terms:
            fac = _low_rank(t) if t.P.size >= 100_000 else None
            if fac is None:
                dense.append(t)
            else:
                low.append(tuple(np.ascontiguousarray(a, dtype=dtype) for a in fac))  # type: ignore[arg-type]
        p_cat = q_cat = None
        if dense:
            p_cat = np.ascontiguousarray(np.concatenate([t.P for t in dense], axis=1), dtype=dtype)
            q_cat = np.ascontiguousarray(np.concatenate([t.Q for t in dense], axis=0), dtype=dtype)
        return cls(p_cat, q_cat, len(dense), low, terms[0].P.shape[0], terms[0].Q.shape[0])

    def apply(self, x: np.ndarray) -> np.ndarray:
        """``(B, N, M)`` → ``(B, R, S)``."""
        b, n, m = x.shape
        y = np.zeros((b, self.rows, self.cols), dtype=x.dtype)
        if self.p_cat is not None and self.q_cat is not None:
            k, s = self.k_dense, self.cols
            w = x.reshape(b * n, m) @ self.q_cat.T  # (B·N, K·S)
            w = w.reshape(b, n, k, s).transpose(0, 2, 1, 3).reshape(b, k * n, s)
            y += np.matmul(self.p_cat, w)
        for up, bp, uq, bq in self.low_rank:
            core = np.matmul(np.matmul(bp, x), bq.T)  # (B, a, b)
            y += np.matmul(np.matmul(up, core), uq.T)
        return y


def _low_rank(t: SeparableTerm) -> tuple[np.ndarray, ...] | None:
    """``(Up, Bp, Uq, Bq)`` with ``P ≈ Up Bp``, ``Q ≈ Uq Bq`` when both are numerically of
    low rank (under a quarter of their smaller side), else None."""
    out: list[np.ndarray] = []
    for mat in (t.P, t.Q):
        u, sv, vt = np.linalg.svd(mat, full_matrices=False)
        rank = int(np.sum(sv > LOW_RANK_TOL * sv[0])) if sv[0] > 0 else 0
        if rank == 0 or rank > min(mat.shape) // 4:
            return None
        out += [u[:, :rank] * sv[:rank], vt[:rank]]
    return tuple(out)


def axis_term_matrices(
    grid: AxisGrid,
    alpha: float,
    beta: float,
    edges_mm: np.ndarray,
    values: np.ndarray,
    factor_derivs: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]],
    n_sub: int = 4,
    chunk_rows: int = 64,
    shifts_mm: np.ndarray | None = None,
) -> np.ndarray:
    """Per-axis matrices for every (profile, smooth factor) pair.

    Parameters
    ----------
    grid, alpha, beta, edges_mm, values
        See :func:`thintact_sdk.simulation.axis.box_box_integrals`; ``values`` is
        ``(V, J)``.
    factor_derivs
        The smooth factors of this axis with their first and second derivatives:
        offsets (mm) of any shape → three arrays ``shape + (L,)``.
    n_sub
        Sub-intervals per pixel for the first moment.
    shifts_mm
        Optional ``(T,)`` displacements (mm): member ``t`` of the family uses the profile
        ``A(m - t)`` (the rotated mask's local shears, :mod:`~thintact_sdk.simulation.rotated`).

    Returns
    -------
    numpy.ndarray
        ``(V, L, n_sensor, n_scene)``: ``(1/pitch)·∫∫ A(alpha·u + beta·s)·f_l(s - u) du ds``,
        i.e. averaged over the sensor pixel and integrated over the scene pixel (mm/mm²);
        with ``shifts_mm``, ``(T, V, L, n_sensor, n_scene)``.
    """
    family = shifts_mm is not None
    shifts = np.atleast_1d(np.asarray(0.0 if shifts_mm is None else shifts_mm, float))
    n_t, n_v = shifts.size, values.shape[0]
    # about chunk_rows·16·n_scene sub-rectangle values per profile and displacement per chunk
    rows_per_chunk = max(1, min(chunk_rows, chunk_rows * 16 // (n_t * n_v * n_sub**2)))
    out: np.ndarray | None = None
    for r0 in range(0, grid.n_sensor, rows_per_chunk):
        r1 = min(grid.n_sensor, r0 + rows_per_chunk)
        # the chunk's sensor centres are displaced from the axis by shift (a window of a
        # larger sensor is itself displaced by its offset)
        shift = grid.sensor_offset_mm + (r0 + (r1 - r0 - 1) / 2 - (grid.n_sensor - 1) / 2) * grid.sensor_pitch_mm
        box, off = _shifted_box(grid, r0, r1, alpha, beta, edges_mm, values, n_sub, shift,
                                shifts)
        centre = off.mean(axis=(2, 3))
        rel = off - centre[..., None, None]  # (r, n, n_sub, n_sub)
        # within-sub-rectangle variance of s - u (exact for a uniform profile there)
        var_in = (grid.sensor_pitch_mm**2 + grid.scene_pitch_mm**2) / (12 * n_sub**2)
        # Σ box·rel^k, k = 0, 1, 2, in one pass over the sub-rectangle integrals
        moments = np.einsum("tvrnab,krnab->ktvrn", box, np.stack([np.ones_like(rel), rel, rel**2]))
        b0, b1 = moments[0], moments[1]
        b2 = moments[2] + var_in * b0  # Σ box·(rel² + var_in)
        f, df, d2f = (np.moveaxis(a, -1, 0)[None, None] for a in factor_derivs(centre))
        blk = (b0[:, :, None] * f + b1[:, :, None] * df + 0.5 * b2[:, :, None] * d2f) \
            / grid.sensor_pitch_mm  # (T, V, L, r, n)
        if out is None:
            out = np.empty((n_t, n_v, f.shape[2], grid.n_sensor, grid.n_scene))
        out[:, :, :, r0:r1] = blk
    assert out is not None
    return out if family else out[0]


def _shifted_box(
    grid: AxisGrid, r0: int, r1: int, alpha: float, beta: float,
    edges_mm: np.ndarray, values: np.ndarray, n_sub: int, shift_mm: float,
    profile_shifts_mm: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`box_box_integrals` for sensor rows ``r0:r1`` of ``grid`` (true positions), for
    every profile displacement: ``(T, V, r, n, n_sub, n_sub)`` and the offsets."""
    sub = AxisGrid(r1 - r0, grid.sensor_pitch_mm, grid.n_scene, grid.scene_pitch_mm)
    # moving the sensor by shift_mm equals moving the mask edges by -alpha·shift_mm
    # and the scene by -shift_mm (offsets s - u shrink by shift_mm); displacing the
    # profile by t equals reading it at m - t
    box, off = box_box_integrals(sub, alpha, beta, edges_mm - alpha * shift_mm, values,
                                 n_sub, n_sub, profile_shifts_mm)
    return box, off - shift_mm


def compress_terms(terms: list[SeparableTerm], rel_tol: float = 1e-6) -> list[SeparableTerm]:
    """The fewest terms representing ``Σ_k P_k ⊗ Q_k`` within ``rel_tol`` (relative
    Frobenius norm of the operator), separately for the open and the coding part.

    The operator rearranged as ``Σ_k vec(P_k) vec(Q_k)ᵀ`` has an SVD computed from the small
    Gram matrices of the ``P_k`` and of the ``Q_k``; its leading singular pairs are the
    optimal Kronecker (separable) terms. New terms are linear combinations of the old ones.
    """
    out: list[SeparableTerm] = []
    for part in ("open", "coding"):
        ts = [t for t in terms if t.part == part]
        if len(ts) <= 1:
            out.extend(ts)
            continue
        # one term per row (contiguous rows: stacking along a column axis wrote strided)
        pm = np.stack([t.P.ravel() for t in ts])
        qm = np.stack([t.Q.ravel() for t in ts])
        vp, sp = _gram_basis(pm)
        vq, sq = _gram_basis(qm)
        mid = (vp * sp).T @ (vq * sq)  # S_p V_pᵀ V_q S_q
        w, sig, zt = np.linalg.svd(mid, full_matrices=False)
        if sig.size == 0 or not sig[0] > 0:  # every term zero (the mask moved out of view)
            out.append(SeparableTerm(np.zeros_like(ts[0].P), np.zeros_like(ts[0].Q), part))
            continue
        energy = np.cumsum(sig[::-1] ** 2)[::-1]  # energy[i] = Σ_{j≥i} σ_j²
        keep = max(1, int(np.sum(np.sqrt(energy / energy[0]) > rel_tol)))
        coef_p = (vp / sp) @ w[:, :keep] * sig[:keep]
        coef_q = (vq / sq) @ zt[:keep].T
        shape_p, shape_q = ts[0].P.shape, ts[0].Q.shape
        # all new terms in one product each side (``keep × size``, rows contiguous): one
        # matrix-vector product per term re-read ``pm`` and ``qm`` ``keep`` times, 85 % of a
        # 16×-binned paper-size rotated kernel's 174 s build
        new_p = coef_p[:, :keep].T @ pm
        new_q = coef_q[:, :keep].T @ qm
        out.extend(SeparableTerm(new_p[i].reshape(shape_p), new_q[i].reshape(shape_q), part)
                   for i in range(keep))
    return out


def _gram_basis(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(V, s)`` with ``rowsᵀ = U diag(s) Vᵀ`` (one term per row), from the Gram matrix
    ``rows rowsᵀ`` (null directions dropped)."""
    d, v = np.linalg.eigh(rows @ rows.T)
    good = d > d.max() * 1e-20
    return v[:, good], np.sqrt(d[good])
