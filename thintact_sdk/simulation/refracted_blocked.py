"""Refraction on wide devices: the kernel filled block by block, no ``D²`` family kept.

The separable refracted kernel (:mod:`~thintact_sdk.simulation.refracted`) tabulates, per
axis, the one-axis matrices ``X(D_y²)`` of *every* x pixel pair at every node of the other
axis's squared offset, and compresses that family by an SVD. On a wide field the crossing
slides by many mask cells across the nodes, so the family is neither small nor of low rank
(``docs/simulator.md``, "refraction"): the whole family must be held before it is
compressed, and its SVD and products take several times its size.

This module evaluates the per-axis tangent-map box integrals along the refracted map
without keeping any family:

- the x pixel pairs ``(c, m)`` are sorted by ``D_x²``, split into classes of ``|D_x|`` (one
  pair extent wide) and taken in groups of at most ``group`` pairs (sized from the block
  budget) that never straddle a class;
- per class and bin level, the y integrals are tabulated at the ``D_x²`` nodes the class
  spans (plus ghost nodes for the cubic interpolation and the derivative), in chunks of y
  pairs sorted by ``D_y²`` (:data:`Y_CHUNK_BYTES`), and kept float32 for every group of the
  class; per group, the x integrals are tabulated at the ``D_y²`` nodes the chunk reaches
  *for the group's pairs only* (:func:`refracted_pair_integrals`);
- both are read by local cubics at each pair of the other axis, and the kernel entries of
  the group's columns are written into a dense ``(R·S, N·M)`` float32 operator, then the
  group's tables are dropped.

**Coupling.** The x crossing depends on the y offset through ``κ(δx² + δy²)`` and vice
versa. Where the other axis's offset moves a pair's crossing by little, it is frozen at
the pair's centre with the first-order correction ``∂X/∂D²·Y₁ + X₁·∂Y/∂D²`` (the separable
path's sum). At wide angles the crossing moves by many µm across a pair and that expansion
is 1-5 % off; there (:func:`coupling_levels`, :data:`COUPLING_BIN_UM`) both pairs are split
into bins of their offset (:func:`coupling_bins`) and every bin of x is expanded about every
bin of y's reference offset and back, to first order in each with the cross term:
``Σ_b Σ_c X_b·Y_c + ∂X_b·Y_c,1 + X_b,1·∂Y_c + ∂X_b,1·∂Y_c,1``, which integrates the
coupling instead of freezing it.

Work is the two axes' tabulation about once each (the y side about twice: neighbouring
classes' reaches overlap; more sub-rectangles on binned pairs) and the fill, memory is the
operator plus one chunk's y tables and one group's x tables (:data:`Y_CHUNK_BYTES`,
:data:`BLOCK_BYTES`). ``progress(done, total)`` is called after each (group, chunk)
step. The operator is refused, before anything is allocated, above :data:`DENSE_MAX_BYTES`,
naming its size. Unrotated masks without diffraction (mask shifts, leakage and the pixel
angular response included).
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

COUPLING_BIN_UM = 2.0
"""Largest move of one axis's crossing point across one coupling bin of the other axis's
pixel pair (µm): a pair whose other-axis offset moves its crossing further is split into
bins of its offset (:func:`coupling_bins`), each expanded about its own reference offset."""

BIN_LEVELS = (1, 2, 3, 4, 6, 8)
"""Bin counts a pair may get (rounded up to one of these; the last is the most)."""

MIN_BINNED_SUB = 8
"""Fewest sub-intervals per pixel of a binned pair (and at least two per bin): a bin's
share of the weighted integrals is taken from its sub-rectangles' centres."""

CLASS_EXTENTS = 1
"""Width of a class of x pairs in ``|D_x|`` (in x pair extents, ``p + p_scene``): the bins a y
pair gets with every x pair of a class are those of the class's largest ``|D_x|``, and the
y pairs' tables are tabulated once per class over the class's ``D_x²`` reach."""

Y_CHUNK_BYTES = 256 * 1024**2
"""Largest y-side working memory of one bin level of a class of x pairs: the float64 table
while it is integrated plus its float32 copy and node derivative (together twice the
float64 table). The y pairs are taken in chunks of this size, each chunk's tables serving
every group of the class."""

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


def coupling_bins(grid: AxisGrid, n_sub: int, n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Split a pixel pair's ``n_sub × n_sub`` sub-rectangles into ``n_bins`` bins of their
    centre offset ``δ = s - u`` (equal widths over the pair's extent).

    Every pair of an axis has the same pattern of sub-rectangle offsets about its centre
    offset ``D``, so one pattern serves the whole axis.

    Returns
    -------
    tuple of numpy.ndarray
        ``(n_bins, n_sub, n_sub)`` 0/1 membership (sensor sub-interval, scene sub-interval)
        and ``(n_bins,)`` each bin's reference offset from ``D`` (mm; the mean of its
        members).
    """
    a = ((np.arange(n_sub) + 0.5) / n_sub - 0.5) * grid.sensor_pitch_mm
    b = ((np.arange(n_sub) + 0.5) / n_sub - 0.5) * grid.scene_pitch_mm
    rel = b[None, :] - a[:, None]
    lo, hi = float(rel.min()), float(rel.max())
    idx = np.minimum(((rel - lo) / max(hi - lo, 1e-300) * n_bins).astype(np.int64), n_bins - 1)
    members = [idx == k for k in range(n_bins) if np.any(idx == k)]
    masks = np.stack([m.astype(float) for m in members])
    refs = np.array([float(rel[m].mean()) for m in members])
    return masks, refs


def refracted_pair_integrals(
    grid: AxisGrid, edges_mm: np.ndarray, values: np.ndarray, factor_derivs: FactorDerivs,
    kappa: TabulatedRadial, other_r2_mm2: np.ndarray, n_sub: int, sensor_idx: np.ndarray,
    scene_idx: np.ndarray, shift_mm: float = 0.0, n_bins: int = 1,
) -> np.ndarray:
    """:func:`~thintact_sdk.simulation.refracted.refracted_axis_family` (``weighted=True``)
    for a list of pixel pairs instead of the whole grid, optionally split into coupling bins.

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
    n_bins
        Bins of the pair's offset (:func:`coupling_bins`): each bin's share of the integrals,
        weighted by ``δ² - δ_b²`` (``δ_b = D + ref_b`` its reference offset) instead of
        ``δ² - D²``. One bin is the whole pair (``ref = 0``).

    Returns
    -------
    numpy.ndarray
        ``(B, 2, T, V, L, P)``: per bin, the plain and the weighted integrals (``B`` the bins
        with members, ``n_bins`` or fewer).
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
    masks, refs = coupling_bins(grid, n_sub, n_bins)
    n_b = refs.size
    # Σ over a bin's sub-rectangles of box·rel^k: one (bin, power) weight per sub-rectangle
    weights = np.einsum("kpab,cab->ckpab", np.stack([rel**k for k in range(5)]), masks)
    weights = weights.reshape(n_b * 5, *rel.shape)
    f, df, d2f = (np.moveaxis(a, -1, 0) for a in factor_derivs(centre))  # (L, P)
    n_v, n_p = values.shape[0], sensor_idx.size
    t_all = np.asarray(other_r2_mm2, float)
    out = np.empty((n_b, 2, t_all.size, n_v, f.shape[0], n_p))
    per_t = max(1, T_BATCH_ELEMENTS // max(1, 4 * n_v * off.size))
    edges = np.asarray(edges_mm, float)
    u_sub = uc[:, :, None]
    # δ² - δ_b² = (δ² - D²) + c_b, c_b = D² - (D + ref_b)²
    c_b = -(2 * centre[None, :] * refs[:, None] + refs[:, None] ** 2)  # (B, P)
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
        moments = np.einsum("vtpab,jpab->jtvp", box, weights)
        moments = moments.reshape((n_b, 5) + moments.shape[1:])  # (B, 5, t, V, P)
        for ib in range(n_b):
            mb = moments[ib]
            b0, b1 = mb[0], mb[1]
            b2 = mb[2] + var_in * b0
            plain = b0[:, :, None] * f + b1[:, :, None] * df + 0.5 * b2[:, :, None] * d2f
            out[ib, 0, t0:t0 + per_t] = plain / p
            out[ib, 1, t0:t0 + per_t] = (_weighted_block(mb, b2, centre, var_in, f, df, d2f)
                                         + c_b[ib] * plain) / p
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
    ls = [w.astype(fam.dtype, copy=False) for w in ls]
    shape = (t.size,) + (1,) * (fam.ndim - 1)
    out = fam[base] * ls[0].reshape(shape)
    for k in range(1, 4):
        out += fam[base + k] * ls[k].reshape(shape)
    return out


def _squared_range(offsets_mm: np.ndarray, half_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Smallest and largest ``δ²`` over a pair of centre offset ``D`` whose offsets span
    ``D ± half`` (mm²)."""
    a = np.abs(offsets_mm)
    return np.maximum(a - half_mm, 0.0) ** 2, (a + half_mm) ** 2


def _reach(offsets_mm: np.ndarray, half_mm: float, binned: bool = True) -> tuple[float, float]:
    """The ``δ²`` range (mm²) the integrals of pairs at centre offsets ``offsets_mm`` are
    read over: their whole extent when binned, else their centres' ``D²``."""
    if not binned:
        d2 = offsets_mm**2
        return float(d2.min()), float(d2.max())
    lo, hi = _squared_range(offsets_mm, half_mm)
    return float(lo.min()), float(hi.max())


def coupling_levels(kappa: TabulatedRadial, dx_mm: np.ndarray, dy_mm: np.ndarray,
                    half_x_mm: float, half_y_mm: float) -> np.ndarray:
    """Coupling bins (:data:`BIN_LEVELS`) each ``(x pair, y pair)`` needs: the larger move of
    one axis's crossing point, ``|D_x|·|κ'(D²)|·Δ(δ_y²)`` and its transpose, across the other
    axis's pair, in steps of at most :data:`COUPLING_BIN_UM`.

    ``dx_mm`` ``(P,)`` and ``dy_mm`` ``(Q,)`` are the pairs' centre offsets; returns ``(P, Q)``.
    """
    lo_x, hi_x = _squared_range(dx_mm, half_x_mm)
    lo_y, hi_y = _squared_range(dy_mm, half_y_mm)
    kd = np.abs(kappa.d1(dx_mm[:, None] ** 2 + dy_mm[None, :] ** 2))
    move_x = np.abs(dx_mm)[:, None] * kd * (hi_y - lo_y)[None, :]
    move_y = np.abs(dy_mm)[None, :] * kd * (hi_x - lo_x)[:, None]
    need = np.ceil(np.maximum(move_x, move_y) * 1e3 / COUPLING_BIN_UM)
    levels = np.asarray(BIN_LEVELS)
    return levels[np.minimum(np.searchsorted(levels, need), levels.size - 1)]


def _node_derivative(fam: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """``∂/∂D²`` of tables ``(B, k, T, ...)`` along their node axis (second order)."""
    if nodes.size > 2:  # uniform nodes: a scalar spacing keeps float32 tables float32
        return np.gradient(fam, float(nodes[1] - nodes[0]), axis=2, edge_order=2)
    return np.zeros_like(fam)


def _fill_block(nodes_y: np.ndarray, fx: np.ndarray, dfx: np.ndarray, refs_x: np.ndarray,
                dx_mm: np.ndarray, nodes_x: np.ndarray, fy: np.ndarray, dfy: np.ndarray,
                refs_y: np.ndarray, dy_mm: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """Kernel entries ``(Q, P)`` of x pairs (offsets ``dx_mm``) and y pairs (``dy_mm``) from
    their binned integrals (``fx`` ``(Bx, 2, Ty, V, L, P)`` on ``nodes_y``, ``fy``
    ``(By, 2, Tx, V, L, Q)`` on ``nodes_x``) and their node derivatives (``dfx``, ``dfy``:
    the plain integrals' only, ``(B, 1, T, V, L, ·)``, when both sides have one bin):
    ``Σ_{b,c} Σ_v coef_v Σ_l`` of the bivariate first-order expansion of bin ``b`` of x about
    bin ``c``'s reference ``δ_y²`` and of bin ``c`` of y about bin ``b``'s ``δ_x²``:
    ``X·Y + ∂X·Y₁ + X₁·∂Y + ∂X₁·∂Y₁``. With one bin each the cross term ``∂X₁·∂Y₁`` is left
    out (the separable path's sum). The tables may be float32 (the sums are then float32)."""
    cross = refs_x.size > 1 or refs_y.size > 1
    coef = coef.astype(fx.dtype)
    block = np.zeros((dy_mm.size, dx_mm.size), fx.dtype)
    for by, ry in enumerate(refs_y):
        at_y = (dy_mm + ry) ** 2  # where the x integrals are read: (Q,)
        for bx, rx in enumerate(refs_x):
            at_x = (dx_mm + rx) ** 2  # where the y integrals are read: (P,)
            x0, x1 = _interp(nodes_y, fx[bx, 0], at_y), _interp(nodes_y, fx[bx, 1], at_y)
            dx0 = _interp(nodes_y, dfx[bx, 0], at_y)
            y0, y1 = _interp(nodes_x, fy[by, 0], at_x), _interp(nodes_x, fy[by, 1], at_x)
            dy0 = _interp(nodes_x, dfy[by, 0], at_x)
            block += np.einsum("v,qvlp,pvlq->qp", coef, x0, y0)
            block += np.einsum("v,qvlp,pvlq->qp", coef, dx0, y1)
            block += np.einsum("v,qvlp,pvlq->qp", coef, x1, dy0)
            if cross:
                block += np.einsum("v,qvlp,pvlq->qp", coef, _interp(nodes_y, dfx[bx, 1], at_y),
                                   _interp(nodes_x, dfy[by, 1], at_x))
    return block


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
    ox, oy = pair_offsets_mm(gx).ravel(), pair_offsets_mm(gy).ravel()  # (S·M,), (R·N,)
    tx, ty = ox**2, oy**2
    half_x = (gx.sensor_pitch_mm + gx.scene_pitch_mm) / 2
    half_y = (gy.sensor_pitch_mm + gy.scene_pitch_mm) / 2
    k0 = float(tables.kappa.value(np.array(0.0)))

    def nodes_for(grid: AxisGrid, lo: float, hi: float) -> np.ndarray:
        width = min((1 - k0) * grid.sensor_pitch_mm, k0 * grid.scene_pitch_mm)
        # the crossing moves by a tenth of the narrower trapezoid side per node: no absolute
        # cap (docs/simulator.md, "Wide angles": the 0.5 um cap changed nothing at 77°)
        return _r2_nodes(lo, hi, tables, grid.max_offset_mm(), width, step_um=math.inf)

    # the nodes cover the pairs' whole δ² range: binned integrals are read at their bins'
    # reference offsets, up to a pair's half extent from its centre
    nodes_y = nodes_for(gx, *_reach(oy, half_y))
    nodes_x = nodes_for(gy, *_reach(ox, half_x))
    n_q = ty.size
    # per x pair of a group: its x integrals at every D_y node (2·T_y·V·L, plus the
    # derivative), and, interpolated at every y pair, X, ∂X, X₁ and Y, ∂Y, Y₁ (6·Q·V·L)
    per_pair = 8.0 * n_v * n_l * (4 * nodes_y.size + 8 * n_q + 2)
    group = int(max(1, min(tx.size, BLOCK_BYTES // per_pair)))
    order = np.argsort(tx, kind="stable")
    # the bins a y pair gets with an x pair are decided by the x pair's class of |D_x| (one
    # class per x pair extent, read at its upper bound), so the kernel does not depend on how
    # the pairs are grouped; groups never straddle a class
    x_class = np.ceil(np.abs(ox) / (2 * CLASS_EXTENTS * half_x)).astype(np.int64)
    classes = []  # (x pairs of the class, its groups)
    for cls in np.unique(x_class):
        members = order[x_class[order] == cls]
        classes.append((members, [members[i:i + group] for i in range(0, members.size, group)]))
    g_out = np.zeros((kp.rows * kp.cols, kp.scene_rows * kp.scene_cols), np.float32)
    g4 = g_out.reshape(kp.rows, kp.cols, kp.scene_rows, kp.scene_cols)
    rq, nq = np.divmod(np.arange(n_q), kp.scene_rows)
    sx, sy = kp.dx_um * 1e-3, kp.dy_um * 1e-3
    # the plan: per class, per bin level, the y pairs in chunks whose y tables fit
    # Y_CHUNK_BYTES; each chunk's y tables serve every group of the class
    plan = []
    for members, cls_groups in classes:
        # the bins every y pair needs with this class (read at its upper bound of |D_x|)
        bound = np.array([x_class[members[0]] * 2 * CLASS_EXTENTS * half_x])
        levels = coupling_levels(tables.kappa, bound, oy, half_x, half_y)[0]  # (Q,)
        for level in np.unique(levels):
            qs = np.flatnonzero(levels == level)
            qs = qs[np.argsort(ty[qs], kind="stable")]  # a chunk spans a short D_y² range
            sl_x = _ghosted(nodes_x, *_reach(ox[members], half_x, level > 1))
            # bytes per y pair: the float64 (B, 2, Tx, V, L) table, and as much again for
            # its float32 copy and derivative
            per_q = 8.0 * 2 * int(level) * (sl_x.stop - sl_x.start) * n_v * n_l * 2
            chunk = int(max(1, min(qs.size, Y_CHUNK_BYTES // per_q)))
            for c0 in range(0, qs.size, chunk):
                plan.append((cls_groups, int(level), qs[c0:c0 + chunk], sl_x))
    n_steps = sum(len(step[0]) for step in plan)
    done, most_bins = 0, 1
    for cls_groups, level, qs, sl_x in plan:
        # sub-rectangles finer than the bins (MIN_BINNED_SUB at least, two per bin)
        n_sub = kp.n_sub if level == 1 else max(kp.n_sub, MIN_BINNED_SUB, 2 * level)
        most_bins = max(most_bins, level)
        _, refs_x = coupling_bins(gx, n_sub, level)
        _, refs_y = coupling_bins(gy, n_sub, level)
        derivs = slice(None) if level > 1 else slice(0, 1)  # ∂X₁, ∂Y₁ for the cross term only
        # y side: these y pairs at the D_x² nodes the class spans, and their derivative
        fy = refracted_pair_integrals(gy, edges, vy, exp.gy_derivs, tables.kappa, nodes_x[sl_x],
                                      n_sub, rq[qs], nq[qs], sy,
                                      n_bins=level).astype(np.float32)  # (B, 2, Tx, V, L, Q)
        dfy = _node_derivative(fy[:, derivs], nodes_x[sl_x])
        # x side: each group's pairs at the D_y² nodes these y pairs reach
        sl_y = _ghosted(nodes_y, *_reach(oy[qs], half_y, level > 1))
        for idx in cls_groups:
            cp, mp = np.divmod(idx, kp.scene_cols)
            fx = refracted_pair_integrals(gx, edges, vx, exp.fx_derivs, tables.kappa, nodes_y[sl_y],
                                          n_sub, cp, mp, sx,
                                          n_bins=level).astype(np.float32)  # (B, 2, Ty, V, L, P)
            dfx = _node_derivative(fx[:, derivs], nodes_y[sl_y])
            block = _fill_block(nodes_y[sl_y], fx, dfx, refs_x, ox[idx],
                                nodes_x[sl_x], fy, dfy, refs_y, oy[qs], coef)
            g4[rq[qs][:, None], cp[None, :], nq[qs][:, None], mp[None, :]] = block
            done += 1
            if progress is not None:
                progress(done, n_steps)
    n_groups = sum(len(c[1]) for c in classes)
    info = {"rank": float(exp.rank), "radiometric_rel_error": exp.rel_error, "terms": 0.0,
            "blocked_groups": float(n_groups), "coupling_bins": float(most_bins)}
    return DirectKernel(g_out, kp.rows, kp.cols, info)


BLOCKED_FROM_BYTES = 256 * 1024**2
"""The separable refracted kernel keeps its ``D²`` families (plain and weighted), their
derivative and their SVDs at once, several times the family's size; from this family size
on (one axis, :func:`~thintact_sdk.simulation.refracted.refracted_family_bytes`) an
unrotated, geometric refracted kernel is filled block by block here instead."""

COUPLING_PROBE_OFFSETS = 512
"""Pair offsets per axis (evenly through the sorted offsets, both ends included) at which
:func:`needs_coupling_bins` evaluates :func:`coupling_levels`."""


def needs_coupling_bins(kp: KernelParams) -> bool:
    """Whether some pixel pair's crossing moves by more than :data:`COUPLING_BIN_UM` across
    the other axis's pair (:func:`coupling_levels` above one bin), probed at
    :data:`COUPLING_PROBE_OFFSETS` offsets per axis: where it does, the separable path's
    frozen coupling is off by up to a few percent (``docs/simulator.md``, "Wide angles")."""
    from thintact_sdk.simulation.refracted import _refracted_tables, pair_offsets_mm

    tables = _refracted_tables(kp)  # κ only: the radiometric expansion is not needed here
    gx, gy = kp.grid_x(), kp.grid_y()

    def probe(grid: AxisGrid) -> np.ndarray:
        o = np.unique(np.abs(pair_offsets_mm(grid).ravel()))
        return o[np.unique(np.linspace(0, o.size - 1, COUPLING_PROBE_OFFSETS).round().astype(np.int64))]

    levels = coupling_levels(tables.kappa, probe(gx), probe(gy),
                             (gx.sensor_pitch_mm + gx.scene_pitch_mm) / 2,
                             (gy.sensor_pitch_mm + gy.scene_pitch_mm) / 2)
    return bool(levels.max() > 1)


def blocked_wanted(kp: KernelParams) -> bool:
    """Whether the kernel of ``kp`` is built by :func:`build_blocked_refracted_kernel`:
    refraction, an unrotated mask, no diffraction, and either a separable family above
    :data:`BLOCKED_FROM_BYTES` or crossings that need coupling bins
    (:func:`needs_coupling_bins`) on an operator within :data:`DENSE_MAX_BYTES` (the
    separable path would freeze the coupling there)."""
    from thintact_sdk.simulation.refracted import refracted_family_bytes

    if kp.n_scene_side == 1.0 or kp.angle_deg != 0.0 or kp.wavelengths_nm is not None or kp.windowed:
        return False
    if refracted_family_bytes(kp) > BLOCKED_FROM_BYTES:
        return True
    return dense_bytes(kp) <= DENSE_MAX_BYTES and needs_coupling_bins(kp)
