"""Separable kernel of a rotated (and shifted) mask: ``Y_c = Σ_k P_k X_c Q_kᵀ`` still.

The pattern is read at ``p = Rot(-θ)(m - (dx, dy))`` (CONTRACTS §5), so with ``c = cos θ``,
``s = sin θ``::

    p_x = c·(m_x - dx) + s·(m_y - dy),    p_y = c·(m_y - dy) - s·(m_x - dx).

Inside the K×K area the mask (and, with diffraction, the intensity behind it, whose field is
separable in the rotated frame because Fresnel propagation is rotation-invariant) is a sum of
products ``A_v(p_x)·B_v(p_y)`` of one-axis profiles. For one (sensor pixel, scene pixel)
pair the crossing points ``m`` spread over a product of two trapezoids of a few µm around
the pair's centre crossing point ``(M_x, M_y)``. There the coupling terms are frozen at the
centre: ``s·(m_y - dy) → t_x = s·(M_y - dy)`` in ``p_x`` and ``s·(m_x - dx) → t_y = s·(M_x - dx)``
in ``p_y``. The first-order error of this vanishes for a single edge (the trapezoids are
symmetric about the centre); what is left comes from cell corners inside a pair's footprint,
of order ``s·footprint``, measured against the brute force in the tests.

The x-factor ``∫∫ A_v(c·m_x + t_x - c·dx)·f_l du ds`` is then the exact one-axis box integral of
the profile displaced by ``-t_x/c`` (:func:`~thintact_sdk.simulation.separable.axis_term_matrices`
with ``shifts_mm``) and depends on the y pair only through ``t_x``. It is tabulated on a fine
grid of displacements (step :data:`SHIFT_STEP_UM`), compressed by an SVD over the displacement
index (``A(t) ≈ Σ_j u_j(t)·B_j``, relative cut :data:`SHIFT_RANK_TOL`) and the weights ``u_j``
are interpolated at each pair's ``t_x``. Each product (x basis matrix × interpolated y weights,
y basis matrix × interpolated x weights) is one separable term; the terms are compressed at the
end like the unrotated kernel's.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from thintact_sdk.errors import KernelSizeError
from thintact_sdk.simulation.axis import AxisGrid, mask_cell_edges_mm
from thintact_sdk.simulation.effects import diffraction, mask_leakage
from thintact_sdk.simulation.params import KernelParams
from thintact_sdk.simulation.radiometry import SeparableExpansion
from thintact_sdk.simulation.separable import SeparableTerm, axis_term_matrices, compress_terms

FactorDerivs = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]
"""The radiometric factors of one axis with their derivatives (see ``axis_term_matrices``)."""

SHIFT_STEP_UM = 0.5
"""Largest step of the tabulated displacements (µm); the weights are interpolated by local
cubics between them. The step is also kept under ``min(w_u, w_s)/SHIFT_STEPS_PER_WIDTH``,
``w_u = α·p`` and ``w_s = β·p_scene`` the two trapezoid widths."""

SHIFT_STEPS_PER_WIDTH = 10.0
"""Displacement steps per (narrower) trapezoid width, for devices with sub-µm pixels."""

SHIFT_RANK_TOL = 3e-4
"""Relative Frobenius error allowed when truncating the displacement family of one profile."""


FAMILY_MAX_BYTES = 2 * 1024**3
"""Largest tabulated displacement family (one axis) the rotated kernels build; the paper's
1024×1280 → 400×512 device at 0.3° would need about 10 GiB per axis, more than the
memory of a typical host."""


def family_bytes(grid: AxisGrid, alpha: float, beta: float, t_lo: float, t_hi: float,
                 n_values: int, rank: int) -> float:
    """Bytes of the displacement family :func:`_shift_family` would tabulate for one axis."""
    width = min(alpha * grid.sensor_pitch_mm, beta * grid.scene_pitch_mm)
    step = min(SHIFT_STEP_UM * 1e-3, width / SHIFT_STEPS_PER_WIDTH)
    n = max(2, int(math.ceil((t_hi - t_lo) / step)) + 3)
    return 8.0 * n * n_values * rank * grid.n_sensor * grid.n_scene


def rotated_family_bytes(kp: KernelParams, rank: int, n_values: int = 2) -> float:
    """Bytes of the larger of the two displacement families of a rotated kernel (``rank``
    the radiometric expansion's, ``n_values`` the profiles per axis: 2 geometric, 4 with
    diffraction)."""
    h = kp.z_mm + kp.d_mm
    alpha, beta = kp.z_mm / h, kp.d_mm / h
    s = abs(math.sin(math.radians(kp.angle_deg)))
    c = math.cos(math.radians(kp.angle_deg))
    gx, gy = kp.grid_x(), kp.grid_y()
    out = 0.0
    for grid, other in ((gx, gy), (gy, gx)):
        cen = pair_centres_mm(other, alpha, beta)
        span = s * float(cen.max() - cen.min()) / c
        out = max(out, family_bytes(grid, alpha, beta, 0.0, span, n_values, rank))
    return out


def check_rotated_size(kp: KernelParams, rank: int, n_values: int = 2,
                       limit_bytes: float = FAMILY_MAX_BYTES) -> None:
    """Refuse (:class:`~thintact_sdk.errors.KernelSizeError`) a rotated kernel whose
    displacement family would exceed ``limit_bytes``, before any of it is allocated."""
    size = rotated_family_bytes(kp, rank, n_values)
    if size > limit_bytes:
        raise KernelSizeError(
            f"physics: a mask rotated by {kp.angle_deg:g}° on this device "
            f"({kp.rows}×{kp.cols} sensor, {kp.scene_rows}×{kp.scene_cols} scene) needs a "
            f"displacement family of {size / 1024**3:.1f} GiB per axis (limit "
            f"{limit_bytes / 1024**3:.1f} GiB): the rotated kernel is made for devices up to "
            "about 128×160 sensor pixels and 50×64 scene pixels"
        )


def check_rotated_terms(kp: KernelParams, rank: int, ranks_x: np.ndarray | list[int],
                        ranks_y: np.ndarray | list[int], limit_bytes: float = FAMILY_MAX_BYTES) -> None:
    """Refuse (:class:`~thintact_sdk.errors.KernelSizeError`) a rotated kernel whose
    separable terms, before compression, would exceed ``limit_bytes``: each profile's block holds ``rank·r_x·r_y`` terms of
    ``R·N + S·M`` values, stacked once more for the compression, plus its two Gram matrices.
    The displacement families can fit (:func:`check_rotated_size`) while this does not (a 6°
    turn on a 128×160 unit needs tens of GiB here; without the check OpenBLAS crashed)."""
    n_terms = rank * int(max(ranks_x)) * int(max(ranks_y))
    per_term = kp.rows * kp.scene_rows + kp.cols * kp.scene_cols
    size = 8.0 * (2.0 * n_terms * per_term + 2.0 * float(n_terms) ** 2)
    if size > limit_bytes:
        raise KernelSizeError(
            f"physics: a mask rotated by {kp.angle_deg:g}° on this device "
            f"({kp.rows}×{kp.cols} sensor, {kp.scene_rows}×{kp.scene_cols} scene) needs "
            f"{n_terms} separable terms ({size / 1024**3:.1f} GiB, limit {limit_bytes / 1024**3:.1f} GiB) "
            "before compression: the rotated kernel is made for turns of a few degrees on devices up "
            "to about 128×160 sensor pixels and 50×64 scene pixels"
        )


def pair_centres_mm(grid: AxisGrid, alpha: float, beta: float) -> np.ndarray:
    """``(n_sensor, n_scene)`` centre crossing points ``alpha·u + beta·s`` of every pixel pair (mm)."""
    return alpha * grid.sensor_centres_mm()[:, None] + beta * grid.scene_centres_mm()[None, :]


def _shift_family(
    grid: AxisGrid, alpha: float, beta: float, edges_mm: np.ndarray, values: np.ndarray,
    factor_derivs: FactorDerivs, n_sub: int, t_lo: float, t_hi: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    """Compressed family of displaced one-axis matrices.

    The profiles displaced by every node ``t`` of a grid over ``[t_lo, t_hi]`` (mm, with
    margins) go through :func:`~thintact_sdk.simulation.separable.axis_term_matrices`; per
    profile the family is factored as ``A(t) ≈ Σ_j u_j(t)·B_j`` (SVD over the node index).

    Returns
    -------
    nodes
        ``(T,)`` displacements (mm) at which the family was tabulated.
    weights
        ``(V, T, r)``: ``u_j`` at the nodes, per profile ``v`` (``r`` the largest rank; the
        unused columns of lower-rank profiles are zero).
    basis
        ``(V, r, L, n_sensor, n_scene)`` basis matrices ``B_j`` per profile.
    ranks
        The rank kept for each profile.
    """
    width = min(alpha * grid.sensor_pitch_mm, beta * grid.scene_pitch_mm)
    step = min(SHIFT_STEP_UM * 1e-3, width / SHIFT_STEPS_PER_WIDTH)
    n = max(2, int(math.ceil((t_hi - t_lo) / step)) + 3)
    nodes = (t_lo + t_hi) / 2 + (np.arange(n) - (n - 1) / 2) * step
    fam = axis_term_matrices(grid, alpha, beta, edges_mm, values, factor_derivs, n_sub,
                             shifts_mm=nodes)  # (T, V, L, r, n)
    weights, basis, ranks = compress_family(fam)
    return nodes, weights, basis, ranks


def compress_family(fam: np.ndarray, rel_tol: float = SHIFT_RANK_TOL, abs_cut: np.ndarray | None = None,
                    ) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Factor a tabulated family ``(T, V, ...)`` per profile ``v`` as
    ``A(t) ≈ Σ_j u_j(t)·B_j`` (SVD over the node index ``t``, relative Frobenius cut
    ``rel_tol``, or the absolute Frobenius cut ``abs_cut[v]`` per profile when given; at
    least rank 1): weights ``(V, T, r)``, basis ``(V, r, ...)`` and the rank of each profile
    (unused columns of lower-rank profiles are zero)."""
    n, n_v = fam.shape[:2]
    per_v = []
    for v in range(n_v):
        mat = fam[:, v].reshape(n, -1)
        # left singular vectors from the small (T × T) Gram matrix
        ev, u = np.linalg.eigh(mat @ mat.T)
        ev, u = np.clip(ev[::-1], 0.0, None), u[:, ::-1]
        tail = np.sqrt(np.cumsum(ev[::-1])[::-1])  # tail[i]: Frobenius norm beyond rank i
        if abs_cut is not None:
            rank = max(1, int(np.sum(tail > abs_cut[v])))
        else:
            rank = max(1, int(np.sum(tail > rel_tol * tail[0]))) if ev[0] > 0 else 1
        per_v.append((u[:, :rank], u[:, :rank].T @ mat))
    r_max = max(b.shape[0] for _, b in per_v)
    weights = np.zeros((n_v, n, r_max))
    basis = np.zeros((n_v, r_max) + fam.shape[2:])
    for v, (u, b) in enumerate(per_v):
        weights[v, :, : u.shape[1]] = u
        basis[v, : b.shape[0]] = b.reshape((b.shape[0],) + fam.shape[2:])
    return weights, basis, [b.shape[0] for _, b in per_v]


def interp_weights(nodes: np.ndarray, weights: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``(V, r) + t.shape``: the weights ``u_j`` at displacements ``t`` by local cubic
    (4-point Lagrange) interpolation on the nodes nearest to each ``t`` (linear with fewer
    than four nodes)."""
    n = nodes.size
    pos = np.clip((t - nodes[0]) / (nodes[1] - nodes[0]), 0.0, n - 1.000001)
    i0 = np.floor(pos).astype(np.int64)
    f = pos - i0
    if n < 4:
        lo, hi = weights[:, i0], weights[:, i0 + 1]
        out = lo * (1 - f)[None, ..., None] + hi * f[None, ..., None]
        return np.moveaxis(out, -1, 1)
    base = np.clip(i0 - 1, 0, n - 4)
    x = pos - base  # position within the 4 nodes base..base+3 (0..3)
    out = np.zeros(weights.shape[:1] + t.shape + weights.shape[2:])
    for k in range(4):
        lk = np.ones_like(x)
        for j in range(4):
            if j != k:
                lk = lk * (x - j) / (k - j)
        out += weights[:, base + k] * lk[None, ..., None]
    return np.moveaxis(out, -1, 1)


def rotated_terms(
    kp: KernelParams, exp: SeparableExpansion,
    profiles_x: tuple[np.ndarray, np.ndarray], profiles_y: tuple[np.ndarray, np.ndarray],
    pairs: list[tuple[str, int, float]],
) -> list[SeparableTerm]:
    """Separable terms of a rotated mask for profile products ``Σ coef·A_v(p_x)·B_v(p_y)``.

    Parameters
    ----------
    kp
        Kernel parameters (angle, shift, grids, distances).
    exp
        The radiometric factor's separable expansion.
    profiles_x, profiles_y
        ``(edges (J+1,), values (V, J))`` of the one-axis profiles in the pattern frame
        (mm, along the pattern's x and y axes).
    pairs
        ``(part, v, coef)``: the term ``coef·A_v(p_x)·B_v(p_y)`` belongs to ``part``
        (``"open"`` or ``"coding"``).

    Returns
    -------
    list of SeparableTerm
        Compressed terms (relative Frobenius tolerance ``kp.compress_tol``).
    """
    h = kp.z_mm + kp.d_mm
    alpha, beta = kp.z_mm / h, kp.d_mm / h
    a = math.radians(kp.angle_deg)
    c, s = math.cos(a), math.sin(a)
    dx, dy = kp.dx_um * 1e-3, kp.dy_um * 1e-3
    gx, gy = kp.grid_x(), kp.grid_y()
    cx = pair_centres_mm(gx, alpha, beta)  # (S, M)
    cy = pair_centres_mm(gy, alpha, beta)  # (R, N)
    # p_x = c·m_x + t_x - c·dx with t_x = s·(M_y - dy): A_v(p_x) = A_v scaled by c, displaced
    # by dx - t_x/c.  p_y = c·m_y - t_y - c·dy with t_y = s·(M_x - dx): displaced by dy + t_y/c.
    t_x = s * (cy - dy)  # (R, N)
    t_y = s * (cx - dx)  # (S, M)
    ex, vx = profiles_x
    ey, vy = profiles_y
    check_rotated_size(kp, exp.rank, max(vx.shape[0], vy.shape[0]))
    nodes_x, w_x, b_x, ranks_x = _shift_family(gx, alpha, beta, ex / c, vx, exp.fx_derivs, kp.n_sub,
                                      dx - t_x.max() / c, dx - t_x.min() / c)
    nodes_y, w_y, b_y, ranks_y = _shift_family(gy, alpha, beta, ey / c, vy, exp.gy_derivs, kp.n_sub,
                                      dy + t_y.min() / c, dy + t_y.max() / c)
    check_rotated_terms(kp, exp.rank, ranks_x, ranks_y)
    # weights of the x family at each y pair, of the y family at each x pair
    u_x = interp_weights(nodes_x, w_x, dx - t_x / c)  # (V, r_x, R, N)
    u_y = interp_weights(nodes_y, w_y, dy + t_y / c)  # (V, r_y, S, M)
    terms: list[SeparableTerm] = []
    for part, v, coef in pairs:
        if coef == 0:
            continue
        rx, ry = ranks_x[v], ranks_y[v]
        block = [SeparableTerm(coef * u_x[v, j] * b_y[v, i, ll], b_x[v, j, ll] * u_y[v, i], part)
                 for ll in range(exp.rank) for j in range(rx) for i in range(ry)]
        # compressing each profile's block first keeps the Gram matrices small
        terms += compress_terms(block, kp.compress_tol / 4)
    return compress_terms(terms, kp.compress_tol)


def geometric_profiles(kp: KernelParams) -> tuple[tuple[np.ndarray, np.ndarray],
                                                   tuple[np.ndarray, np.ndarray],
                                                   list[tuple[str, int, float]]]:
    """Pattern-frame profiles of the sharp mask: open (aperture) and coding (±1) halves."""
    k = len(kp.phi)
    edges = mask_cell_edges_mm(k, kp.feature_um * 1e-3)
    c_o, c_c = mask_leakage.intensity_coefficients(kp.leakage)
    px = (edges, np.stack([np.ones(k), np.asarray(kp.phi, float)]))
    py = (edges, np.stack([np.ones(k), np.asarray(kp.phi_rows, float)]))
    return px, py, [("open", 0, c_o), ("coding", 1, c_c)]


def diffraction_profiles(kp: KernelParams, wavelength_nm: float
                         ) -> tuple[tuple[np.ndarray, np.ndarray],
                                    tuple[np.ndarray, np.ndarray],
                                    list[tuple[str, int, float]]]:
    """Pattern-frame intensity profiles behind the mask at one wavelength
    (:func:`thintact_sdk.simulation.effects.diffraction.axis_intensity_profiles`, four per axis)."""
    h = kp.z_mm + kp.d_mm
    alpha, beta = kp.z_mm / h, kp.d_mm / h
    k = len(kp.phi)
    edges = mask_cell_edges_mm(k, kp.feature_um * 1e-3)
    s = abs(math.sin(math.radians(kp.angle_deg)))
    out = []
    for grid, phi, grid_o in ((kp.grid_x(), kp.phi, kp.grid_y()), (kp.grid_y(), kp.phi_rows,
                                                                    kp.grid_x())):
        half = max(abs(v) for v in grid.crossing_span_mm(alpha, beta))
        half_o = max(abs(v) for v in grid_o.crossing_span_mm(alpha, beta))
        reach = half + s * half_o + abs(kp.dx_um * 1e-3) + abs(kp.dy_um * 1e-3) \
            + 4 * grid.sensor_pitch_mm + 4 * grid.scene_pitch_mm
        out.append(diffraction.axis_intensity_profiles(
            edges, np.asarray(phi, float), -reach, reach, wavelength_nm, kp.z_mm, kp.d_mm))
    a_o, a_c = mask_leakage.amplitude_coefficients(kp.leakage)
    pairs = [("open", 0, a_o**2), ("open", 1, a_c**2), ("coding", 2, 2 * a_o * a_c),
             ("coding", 3, -2 * a_o * a_c)]
    return out[0], out[1], pairs
