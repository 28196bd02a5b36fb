"""Refraction on wide devices: the kernel filled block by block, no ``D²`` family kept.

The separable refracted kernel (:mod:`~thintact_sdk.simulation.refracted`) tabulates, per
axis, the one-axis matrices ``X(D_y²)`` of *every* x pixel pair at every node of the other
axis's squared offset, and compresses that family by an SVD. On a wide field the crossing
slides by many mask cells across the nodes, so the family is neither small nor of low rank
(``docs/simulator.md``, "refraction"): the whole family must be held before it is
compressed, and its SVD and products take several times its size.

This module evaluates the *same* integrals (the per-axis tangent-map box integrals along the
refracted map with the other axis's offset frozen at the pair's centre, plus the first-order
coupling correction ``∂X/∂D²·Y₁ + X₁·∂Y/∂D²``) without keeping any family:

- the x pixel pairs ``(c, m)`` are sorted by ``D_x²`` and taken in groups of at most
  ``group`` pairs (sized from the block budget);
- for a group, the x integrals are tabulated at every ``D_y²`` node *for the group's pairs
  only* (:func:`refracted_pair_integrals`), and the y family only at the few ``D_x²`` nodes
  the group's pairs span (plus ghost nodes for the cubic interpolation and the derivative);
- both are read by the same local cubics at each pair of the other axis, and the kernel
  entries ``Σ_v c_v Σ_l [X·Y + ∂X·Y₁ + X₁·∂Y]`` of the group's columns are written into a
  dense ``(R·S, N·M)`` float32 operator, then the group's tables are dropped.

Work is the two families' tabulation once (as the separable path), memory is the operator
plus one group's tables (:data:`BLOCK_BYTES`). The operator is refused, before anything is
allocated, above :data:`DENSE_MAX_BYTES`, naming its size. Unrotated masks without
diffraction (mask shifts, leakage and the pixel angular response included).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from thintact_sdk.errors import ThinTactError
from thintact_sdk.simulation.axis import AxisGrid, mask_cell_edges_mm, second_antiderivative
from thintact_sdk.simulation.direct import DirectKernel
from thintact_sdk.simulation.effects import mask_leakage
from thintact_sdk.simulation.params import KernelParams
from thintact_sdk.simulation.radiometry import TabulatedRadial
from thintact_sdk.simulation.rotated import FactorDerivs

DENSE_MAX_BYTES = 2 * 1024**3
"""Largest dense refracted operator (float32, ``R·S·N·M·4`` bytes) built."""

BLOCK_BYTES = 192 * 1024**2
"""Working memory of one group of columns (its tables and interpolated values)."""

GHOST_NODES = 3
"""Nodes kept on each side of a group's ``D²`` range: the cubic reads one below and two
above, the second-order derivative one more on each side."""

T_BATCH_ELEMENTS = 2_000_000
"""Sub-rectangle corner values evaluated at once by :func:`refracted_pair_integrals`."""


def dense_bytes(kp: KernelParams) -> float:
    """Bytes of the dense float32 operator of ``kp``: ``R·S·N·M·4``."""
    return 4.0 * kp.rows * kp.cols * kp.scene_rows * kp.scene_cols


def check_dense_size(kp: KernelParams, limit_bytes: float = DENSE_MAX_BYTES) -> None:
    """Refuse (``ThinTactError``, nothing allocated) an operator above ``limit_bytes``."""
    size = dense_bytes(kp)
    if size > limit_bytes:
        raise ThinTactError(
            f"physics: refraction on this device needs a dense kernel of {size / 1024**3:.1f} GiB "
            f"({kp.rows}×{kp.cols} → {kp.scene_rows}×{kp.scene_cols}; float32, limit "
            f"{limit_bytes / 1024**3:.0f} GiB): at this field of view the refracted kernel has no "
            "compact separable form (the crossing slides by many mask cells across the scene, "
            "docs/simulator.md 'refraction'); bin the sensor or crop the scene")


def refracted_pair_integrals(
    grid: AxisGrid, edges_mm: np.ndarray, values: np.ndarray, factor_derivs: FactorDerivs,
    kappa: TabulatedRadial, other_r2_mm2: np.ndarray, n_sub: int, sensor_idx: np.ndarray,
    scene_idx: np.ndarray, shift_mm: float = 0.0,
) -> np.ndarray:
    """:func:`~thintact_sdk.simulation.refracted.refracted_axis_family` (``weighted=True``)
    for a list of pixel pairs instead of the whole grid.

    Parameters
    ----------
    grid, edges_mm, values, factor_derivs, kappa, n_sub
        As in ``refracted_axis_family``.
    other_r2_mm2
        ``(T,)`` frozen squared other-axis offsets ``D²`` (mm²).
    sensor_idx, scene_idx
        ``(P,)`` this axis's sensor and scene pixel index of each pair.
    shift_mm
        The profile is read at ``m - shift``.

    Returns
    -------
    numpy.ndarray
        ``(2, T, V, L, P)``: the plain and the ``(δ² - D²)``-weighted integrals.
    """
    from thintact_sdk.simulation.refracted import _weighted_block

    p, ps = grid.sensor_pitch_mm, grid.scene_pitch_mm
    ue = grid.sensor_edges_mm(n_sub)
    se = grid.scene_edges_mm(n_sub)
    uc = ((ue[1:] + ue[:-1]) / 2).reshape(grid.n_sensor, n_sub)[sensor_idx]  # (P, a)
    sc = ((se[1:] + se[:-1]) / 2).reshape(grid.n_scene, n_sub)[scene_idx]  # (P, b)
    hu, hs = p / (2 * n_sub), ps / (2 * n_sub)
    var_in = (p**2 + ps**2) / (12 * n_sub**2)
    off = sc[:, None, :] - uc[:, :, None]  # (P, a, b)
    centre = off.mean(axis=(1, 2))  # (P,)
    rel = off - centre[:, None, None]
    powers = np.stack([rel**k for k in range(5)])  # (5, P, a, b)
    f, df, d2f = (np.moveaxis(a, -1, 0) for a in factor_derivs(centre))  # (L, P)
    n_v, n_p = values.shape[0], sensor_idx.size
    t_all = np.asarray(other_r2_mm2, float)
    out = np.empty((2, t_all.size, n_v, f.shape[0], n_p))
    per_t = max(1, T_BATCH_ELEMENTS // max(1, 4 * n_v * off.size))
    edges = np.asarray(edges_mm, float)
    u_sub = uc[:, :, None]
    for t0 in range(0, t_all.size, per_t):
        t = t_all[t0:t0 + per_t, None, None, None]  # (t, 1, 1, 1)
        r2 = off**2 + t  # (t, P, a, b)
        k = kappa.value(r2)
        gp = k + 2 * off**2 * kappa.d1(r2)
        m0 = u_sub + off * k - shift_mm
        a_u, b_s = (1 - gp) * hu, gp * hs
        corners = np.stack([m0 + a_u + b_s, m0 - a_u + b_s, m0 + a_u - b_s, m0 - a_u - b_s])
        d = second_antiderivative(edges, values, corners)  # (V, 4, t, P, a, b)
        box = (d[:, 0] - d[:, 1] - d[:, 2] + d[:, 3]) / ((1 - gp) * gp)  # (V, t, P, a, b)
        moments = np.einsum("vtpab,kpab->ktvp", box, powers)  # (5, t, V, P)
        b0, b1 = moments[0], moments[1]
        b2 = moments[2] + var_in * b0
        out[0, t0:t0 + per_t] = (b0[:, :, None] * f + b1[:, :, None] * df
                                 + 0.5 * b2[:, :, None] * d2f) / p
        out[1, t0:t0 + per_t] = _weighted_block(moments, b2, centre, var_in, f, df, d2f) / p
    return out


def _ghosted(nodes: np.ndarray, t_lo: float, t_hi: float) -> slice:
    """Index range of the uniform ``nodes`` covering ``[t_lo, t_hi]`` with ghost nodes."""
    step = nodes[1] - nodes[0]
    i0 = int(math.floor((t_lo - nodes[0]) / step)) - GHOST_NODES
    i1 = int(math.ceil((t_hi - nodes[0]) / step)) + GHOST_NODES + 1
    i0, i1 = max(0, i0), min(nodes.size, i1)
    if i1 - i0 < 4:  # the cubic needs four nodes
        i0, i1 = max(0, min(i0, nodes.size - 4)), min(nodes.size, max(i1, i0 + 4))
    return slice(i0, i1)


def _interp(nodes: np.ndarray, fam: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Local cubics of ``fam`` ``(T, ...)`` on uniform ``nodes`` at ``t`` ``(Q,)``:
    ``(Q, ...)``."""
    from thintact_sdk.simulation.refracted import _lagrange4

    base, ls = _lagrange4(nodes, t)
    shape = (t.size,) + (1,) * (fam.ndim - 1)
    out = fam[base] * ls[0].reshape(shape)
    for k in range(1, 4):
        out += fam[base + k] * ls[k].reshape(shape)
    return out


def build_blocked_refracted_kernel(
    kp: KernelParams, progress: Callable[[int, int], None] | None = None,
) -> DirectKernel:
    """The refracted kernel of an unrotated mask without diffraction as a dense float32
    ``(R·S, N·M)`` operator, filled group by group of x pixel pairs (module docstring).

    Raises
    ------
    ThinTactError
        Before allocating, when the operator exceeds :data:`DENSE_MAX_BYTES`, or for a
        rotated mask or diffraction (not built here).
    """
    from thintact_sdk.simulation.refracted import _r2_nodes, _tables_and_expansion, pair_offsets_mm

    if kp.angle_deg != 0.0 or kp.wavelengths_nm is not None:
        raise ThinTactError("physics: the blocked refraction kernel is built for an unrotated mask "
                            "without diffraction")
    check_dense_size(kp)
    tables, exp = _tables_and_expansion(kp)
    gx, gy = kp.grid_x(), kp.grid_y()
    k_cells = len(kp.phi)
    edges = mask_cell_edges_mm(k_cells, kp.feature_um * 1e-3)
    vx = np.stack([np.ones(k_cells), np.asarray(kp.phi, float)])
    vy = np.stack([np.ones(k_cells), np.asarray(kp.phi_rows, float)])
    c_o, c_c = mask_leakage.intensity_coefficients(kp.leakage)
    coef = np.array([c_o, c_c])
    n_v, n_l = 2, exp.rank
    ox, oy = pair_offsets_mm(gx), pair_offsets_mm(gy)  # (S, M), (R, N)
    tx, ty = (ox**2).ravel(), (oy**2).ravel()
    k0 = float(tables.kappa.value(np.array(0.0)))

    def nodes_for(grid: AxisGrid, other_t: np.ndarray) -> np.ndarray:
        width = min((1 - k0) * grid.sensor_pitch_mm, k0 * grid.scene_pitch_mm)
        return _r2_nodes(float(other_t.min()), float(other_t.max()), tables, grid.max_offset_mm(), width)

    nodes_y = nodes_for(gx, ty)  # the x integrals' nodes (in D_y²)
    nodes_x = nodes_for(gy, tx)  # the y integrals' nodes (in D_x²)
    n_q = ty.size
    # per x pair of a group: its x integrals at every D_y node (2·T_y·V·L), and, interpolated
    # at every y pair, X, ∂X, X₁ and Y, ∂Y, Y₁ (6·Q·V·L)
    per_pair = 8.0 * n_v * n_l * (2 * nodes_y.size + 6 * n_q + 2)
    group = int(max(1, min(tx.size, BLOCK_BYTES // per_pair)))
    order = np.argsort(tx, kind="stable")
    g_out = np.zeros((kp.rows * kp.cols, kp.scene_rows * kp.scene_cols), np.float32)
    g4 = g_out.reshape(kp.rows, kp.cols, kp.scene_rows, kp.scene_cols)
    rq, nq = np.divmod(np.arange(n_q), kp.scene_rows)
    n_groups = -(-tx.size // group)
    sx, sy = kp.dx_um * 1e-3, kp.dy_um * 1e-3
    for gi in range(n_groups):
        idx = order[gi * group:(gi + 1) * group]
        cp, mp = np.divmod(idx, kp.scene_cols)
        # x side: the group's pairs at every D_y² node; ∂/∂D² on the nodes
        fx = refracted_pair_integrals(gx, edges, vx, exp.fx_derivs, tables.kappa, nodes_y,
                                      kp.n_sub, cp, mp, sx)  # (2, Ty, V, L, P)
        dfx = np.gradient(fx[0], nodes_y, axis=0, edge_order=2)
        x_at = _interp(nodes_y, fx[0], ty)  # (Q, V, L, P)
        dx_at = _interp(nodes_y, dfx, ty)
        x1_at = _interp(nodes_y, fx[1], ty)
        del fx, dfx
        # y side: the whole y grid at the group's few D_x² nodes
        sl = _ghosted(nodes_x, float(tx[idx].min()), float(tx[idx].max()))
        nodes = nodes_x[sl]
        from thintact_sdk.simulation.refracted import refracted_axis_family

        fy = refracted_axis_family(gy, edges, vy, exp.gy_derivs, tables.kappa, nodes, kp.n_sub,
                                   sy, weighted=True)  # (2, Tg, V, L, R, N)
        fy = fy.reshape(fy.shape[:4] + (n_q,))
        dfy = np.gradient(fy[0], nodes, axis=0, edge_order=2) if nodes.size > 2 else np.zeros_like(fy[0])
        y_at = _interp(nodes, fy[0], tx[idx])  # (P, V, L, Q)
        dy_at = _interp(nodes, dfy, tx[idx])
        y1_at = _interp(nodes, fy[1], tx[idx])
        del fy, dfy
        block = np.einsum("v,qvlp,pvlq->qp", coef, x_at, y_at)
        block += np.einsum("v,qvlp,pvlq->qp", coef, dx_at, y1_at)
        block += np.einsum("v,qvlp,pvlq->qp", coef, x1_at, dy_at)
        g4[rq[:, None], cp[None, :], nq[:, None], mp[None, :]] = block
        if progress is not None:
            progress(gi + 1, n_groups)
    info = {"rank": float(exp.rank), "radiometric_rel_error": exp.rel_error, "terms": 0.0,
            "blocked_groups": float(n_groups)}
    return DirectKernel(g_out, kp.rows, kp.cols, info)


BLOCKED_FROM_BYTES = 256 * 1024**2
"""The separable refracted kernel keeps its ``D²`` families (plain and weighted), their
derivative and their SVDs at once, several times the family's size; from this family size
on (one axis, :func:`~thintact_sdk.simulation.refracted.refracted_family_bytes`) an
unrotated, geometric refracted kernel is filled block by block here instead."""


def blocked_wanted(kp: KernelParams) -> bool:
    """Whether the kernel of ``kp`` is built by :func:`build_blocked_refracted_kernel`:
    refraction, an unrotated mask, no diffraction, and a separable family above
    :data:`BLOCKED_FROM_BYTES`."""
    from thintact_sdk.simulation.refracted import refracted_family_bytes

    if kp.n_scene_side == 1.0 or kp.angle_deg != 0.0 or kp.wavelengths_nm is not None or kp.windowed:
        return False
    return refracted_family_bytes(kp) > BLOCKED_FROM_BYTES
