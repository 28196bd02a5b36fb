"""Separable kernel with refraction (CONTRACTS §5 ``refraction``): ``Y_c = Σ_k P_k X_c Q_kᵀ``.

With a scene-side medium of index ``n`` a ray from scene point ``s`` to sensor point ``u``
crosses the mask at ``m = u + (s - u)·κ(ρ²)``, ``ρ = |s - u|`` (Snell's law,
:func:`thintact_sdk.simulation.effects.refraction.crossing_fraction_and_factor`), and carries the radial
irradiance factor ``F(ρ²)``. Per axis, ``m_x = u_x + dx·κ(dx² + dy²)``: the x crossing depends
on the y offset only through ``κ``. For one (sensor pixel, scene pixel) pair the y offset
``dy`` is frozen at the y pair's centre offset ``D_y`` inside ``κ``, so the x-factor is a
one-axis box integral of the mask profile along the *curved* map ``m_x(u_x, s_x; D_y²)``
(the unrotated kernel adds the first-order correction ``∂X/∂D²·(dy² - D_y²)`` as more
separable products, see :func:`refracted_terms`; the rotated one too, within an error budget):

- the pixel pair is split into ``n_sub × n_sub`` sub-rectangles; on each, the map is replaced
  by its tangent at the sub-rectangle's centre, ``m ≈ M + (1 - g')(u - u_c) + g'(s - s_c)``
  with ``g(dx) = dx·κ(dx² + D_y²)`` and ``g' = κ + 2dx²κ'`` the *local* widths (not the
  paraxial ``κ0``), and integrated exactly with the profile's second antiderivative
  (:func:`~thintact_sdk.simulation.axis.second_antiderivative`);
- the radial factor ``F`` is expanded as ``Σ_l f_l(dx)·g_l(dy)``
  (:class:`~thintact_sdk.simulation.radiometry.SeparableExpansion` built on the tabulated
  ``F``) and enters through its value and derivatives at the pair's centre offset with the
  sub-rectangles' moments, as in the straight-ray kernel.

The x-matrices depend on the y pair only through ``D_y²``; they are tabulated on a uniform
grid of ``D_y²`` (the crossing moves by at most :data:`CROSSING_STEP_UM` between nodes),
compressed by an SVD over the node index and their weights interpolated by local cubics at
every y pair's ``D_y²`` (:mod:`~thintact_sdk.simulation.rotated`'s machinery); likewise for y.
Each (x basis × interpolated y weights) ⊗ (y basis × interpolated x weights) product is one
separable term. Diffraction composes: its intensity profiles (functions of the crossing
point) are integrated along the same map, with the paraxial Fresnel width of a scene gap
``z/n`` (the wave's phase curvature in the medium).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial

import numpy as np

from thintact_sdk.errors import ThinTactError
from thintact_sdk.host.build_threads import build_threads, per_channel_by_wavelength, thread_map
from thintact_sdk.simulation.axis import AxisGrid, mask_cell_edges_mm, second_antiderivative
from thintact_sdk.simulation.effects import diffraction, mask_leakage, refraction
from thintact_sdk.simulation.params import KernelParams
from thintact_sdk.simulation.radiometry import SeparableExpansion, TabulatedRadial
from thintact_sdk.simulation.rotated import (
    SHIFT_RANK_TOL,
    SHIFT_STEP_UM,
    SHIFT_STEPS_PER_WIDTH,
    FactorDerivs,
    compress_family,
)
from thintact_sdk.simulation.separable import SeparableKernel, SeparableTerm, compress_terms

CROSSING_STEP_UM = 0.5
"""Largest move of the crossing point between two tabulated ``D²`` nodes (µm); also kept
under a tenth of the narrower trapezoid width."""

FAMILY_RANK_TOL = 1e-4
"""Relative Frobenius cut of the SVD over the ``D²`` nodes."""

CORRECTION_RANK_TOL = 1e-2
"""The same cut for the families of the first-order coupling correction (the ``D²``
derivative and the ``(δ² - D²)``-weighted family), whose products are ~1e-3 of the kernel
at 20° offsets: a 1 % cut of them is ~1e-5 of the kernel."""

CORRECTION_COMPRESS_TOL = 1e-2
"""Relative cut when the correction products are compressed (separately from the main
products, relative to their own norm)."""

CORRECTION_ERROR = 5e-5
"""Error of the kernel (relative Frobenius, a twentieth of the contract's 1e-3) the rotated +
refracted path may spend on truncating its coupling correction: the correction's factors are
cut at ``CORRECTION_ERROR / size`` of their own norm (``size`` the correction's estimated
relative size, :func:`correction_size`), at most 0.5 and at least :data:`CORRECTION_RANK_TOL`.
Its two-parameter derivative family has ranks 33-43 at a 1 % cut on golden-mini at 0.3°
(126-203 with the unrotated path's cut), so a fixed cut made that kernel take minutes."""

MERGE_TERMS = 300
"""Terms accumulated before an intermediate compression (rotated + refracted kernel)."""

ONE_SHOT_TERMS = 2500
"""Up to this many products (rotated + refracted kernel) are compressed in one go (one Gram
matrix each side, ~(R·N + S·M)·terms·8 bytes); beyond, block by block."""

TABLE_POINTS = 4001
"""Samples of the Snell solution (uniform in ρ²) behind the splines of κ and F."""


class RefractedTables:
    """``κ(ρ²)`` and ``F(ρ²)`` of a refracting scene gap as splines in ``ρ²``.

    Parameters
    ----------
    z_mm, d_mm, n, exponent
        Scene-to-mask gap (medium of index ``n``), mask-to-sensor gap (air) and the pixel
        angular exponent ``p``.
    rho_max_mm
        Largest lateral offset the device uses.
    """

    def __init__(self, z_mm: float, d_mm: float, n: float, exponent: float,
                 rho_max_mm: float) -> None:
        # uniform in ρ² (the splines' variable)
        rho = np.sqrt(np.linspace(0.0, (rho_max_mm * 1.05 + 1e-3) ** 2, TABLE_POINTS))
        kappa, factor = refraction.crossing_fraction_and_factor(rho, z_mm, d_mm, n, exponent)
        self.kappa = TabulatedRadial.from_samples(rho, kappa)
        self.factor = TabulatedRadial.from_samples(rho, factor)


FAMILY_MAX_BYTES = 2 * 1024**3
"""Largest tabulated family (one axis) the refracted kernels build."""


def _check_family_size(grid: AxisGrid, n_members: int, n_values: int, rank: int) -> None:
    """Refuse (``ThinTactError``) a family that would not fit in :data:`FAMILY_MAX_BYTES`."""
    size = 8.0 * n_members * n_values * rank * grid.n_sensor * grid.n_scene
    if size > FAMILY_MAX_BYTES:
        raise ThinTactError(
            f"physics: refraction on this device needs {n_members} tabulated one-axis members "
            f"of {grid.n_sensor}×{grid.n_scene} pixels ({size / 1024**3:.0f} GiB, limit "
            f"{FAMILY_MAX_BYTES / 1024**3:.0f} GiB): the separable refraction kernel is made for "
            "devices up to about 128×160 sensor pixels and a few degrees of view"
        )


def refracted_family_bytes(kp: KernelParams, n_values: int = 2) -> float:
    """Bytes of the larger one-axis ``D²`` family an unrotated refracted kernel would
    tabulate (checked by :func:`_check_family_size` before it is built)."""
    tables, exp = _tables_and_expansion(kp)
    k0 = float(tables.kappa.value(np.array(0.0)))
    out = 0.0
    for grid, other in ((kp.grid_x(), kp.grid_y()), (kp.grid_y(), kp.grid_x())):
        o2 = pair_offsets_mm(other) ** 2
        width = min((1 - k0) * grid.sensor_pitch_mm, k0 * grid.scene_pitch_mm)
        nodes = _r2_nodes(float(o2.min()), float(o2.max()), tables, grid.max_offset_mm(), width)
        out = max(out, 8.0 * nodes.size * n_values * exp.rank * grid.n_sensor * grid.n_scene)
    return out


def refracted_axis_family(
    grid: AxisGrid, edges_mm: np.ndarray, values: np.ndarray, factor_derivs: FactorDerivs,
    kappa: TabulatedRadial, other_r2_mm2: np.ndarray, n_sub: int,
    shifts_mm: np.ndarray | float = 0.0, chunk_rows: int = 64, weighted: bool = False,
) -> np.ndarray:
    """One-axis matrices along the refracted map, for every frozen other-axis offset.

    Parameters
    ----------
    grid
        This axis's sensor and scene pixel grids.
    edges_mm, values
        ``(J+1,)`` edges and ``(V, J)`` values of piecewise-constant mask profiles (zero
        outside), in this axis's mask coordinate.
    factor_derivs
        This axis's radial-factor terms with derivatives (``(..., L)`` each).
    kappa
        ``κ(ρ²)``.
    other_r2_mm2
        ``(T,)`` squared other-axis offsets ``D²`` (mm²).
    n_sub
        Sub-intervals per pixel (tangent maps and factor moments).
    shifts_mm
        The profile is read at ``m - shift`` (mask displacement along this axis), for each
        of these ``(H,)`` displacements (or one).

    weighted
        Also return the same integrals weighted by ``δ² - D²`` (``δ = s - u``, ``D`` the
        pair's centre offset): the moments the other axis's first-order coupling correction
        needs (see :func:`refracted_terms`).

    Returns
    -------
    numpy.ndarray
        ``(T, H, V, L, n_sensor, n_scene)``: ``(1/pitch)·∫∫ A(m(u, s) - shift)·f_l(s - u) du ds``
        (``(T, V, L, ...)`` for a scalar ``shifts_mm``); with ``weighted``, a leading axis of
        two: the plain and the ``(δ² - D²)``-weighted integrals.
    """
    scalar = np.ndim(shifts_mm) == 0
    shifts = np.atleast_1d(np.asarray(shifts_mm, float))
    n_h = shifts.size
    p, ps = grid.sensor_pitch_mm, grid.scene_pitch_mm
    ue = grid.sensor_edges_mm(n_sub)
    se = grid.scene_edges_mm(n_sub)
    uc_all = (ue[1:] + ue[:-1]) / 2
    sc = (se[1:] + se[:-1]) / 2
    hu, hs = p / (2 * n_sub), ps / (2 * n_sub)
    var_in = (p**2 + ps**2) / (12 * n_sub**2)
    n_t, n_v = other_r2_mm2.size, values.shape[0]
    r_all, n = grid.n_sensor, grid.n_scene
    rows_per_chunk = max(1, min(r_all, chunk_rows * 16 // (n_v * n_h * n_sub**2)))
    out: np.ndarray | None = None
    edges = np.asarray(edges_mm, float)
    for r0 in range(0, r_all, rows_per_chunk):
        r1 = min(r_all, r0 + rows_per_chunk)
        uc = uc_all[r0 * n_sub:r1 * n_sub]
        dx = sc[None, :] - uc[:, None]  # (r·n_sub, n·n_sub)
        off = dx.reshape(r1 - r0, n_sub, n, n_sub)  # (r, a, n, b): sub-rectangle (a, b) of pair (r, n)
        centre = off.mean(axis=(1, 3))  # (r, n)
        rel = off - centre[:, None, :, None]
        # powers rel^k of the sub-rectangles' offsets from their pair's centre, for the
        # moments Σ box·rel^k of every node in one pass (k ≤ 4 with the weighted integrals)
        powers = np.stack([rel**k for k in range(5 if weighted else 3)])
        f, df, d2f = (np.moveaxis(a, -1, 0) for a in factor_derivs(centre))  # (L, r, n)
        for it, t in enumerate(other_r2_mm2):
            r2 = dx**2 + t
            k = kappa.value(r2)
            gp = k + 2 * dx**2 * kappa.d1(r2)  # g'(dx) = ∂m/∂s; 1 - g' = ∂m/∂u
            m0 = uc[:, None] + dx * k
            a_u, b_s = (1 - gp) * hu, gp * hs
            corners = np.stack([m0 + a_u + b_s, m0 - a_u + b_s, m0 + a_u - b_s, m0 - a_u - b_s])
            d = second_antiderivative(edges, values, corners[None] - shifts[:, None, None, None])
            # d: (V, H, 4, ...)
            box = (d[:, :, 0] - d[:, :, 1] - d[:, :, 2] + d[:, :, 3]) / ((1 - gp) * gp)
            box = box.reshape(n_v, n_h, r1 - r0, n_sub, n, n_sub)
            moments = np.einsum("vhranb,kranb->khvrn", box, powers)  # Σ box·rel^k: (K, H, V, r, n)
            b0, b1 = moments[0], moments[1]
            b2 = moments[2] + var_in * b0  # Σ box·(rel² + var_in)
            blk = (b0[:, :, None] * f + b1[:, :, None] * df + 0.5 * b2[:, :, None] * d2f) / p
            if out is None:
                out = np.empty((1 + weighted, n_t, n_h, n_v, f.shape[0], r_all, n))
            out[0, it, :, :, :, r0:r1] = blk
            if weighted:
                # δ² - D² = 2D·ε + ε² with ε = rel + e (e: the spread inside a sub-rectangle,
                # mean 0, variance var_in), times the factor's Taylor series in ε
                out[1, it, :, :, :, r0:r1] = _weighted_block(moments, b2, centre, var_in, f, df,
                                                             d2f) / p
    assert out is not None
    out = out[:, :, 0] if scalar else out
    return out if weighted else out[0]


def _weighted_block(moments: np.ndarray, b2: np.ndarray, centre: np.ndarray, var_in: float,
                    f: np.ndarray, df: np.ndarray, d2f: np.ndarray) -> np.ndarray:
    """``Σ box·E[(δ² - D²)·(f + f'·ε + f''·ε²/2)]`` over a pair's sub-rectangles.

    ``moments``: ``(5, H, V, r, n)`` raw moments ``S_k = Σ box·rel^k`` of the sub-rectangle
    integrals about the pair's centre offset ``centre`` ``(r, n)``; ``b2 = S_2 + var_in·S_0``;
    ``f, df, d2f``: ``(L, r, n)``. With ``ε = rel + e`` (``e`` the spread inside a
    sub-rectangle, mean 0, variance ``var_in``), ``δ² - D² = 2D·ε + ε²`` and
    ``E[ε²] = rel² + var_in``, ``E[ε³] = rel³ + 3·rel·var_in``,
    ``E[ε⁴] ≈ rel⁴ + 6·rel²·var_in + 1.8·var_in²`` (its share is negligible). Returns
    ``(H, V, L, r, n)``.
    """
    s0, s1, _, s3, s4 = moments
    two_d = 2 * centre
    e3 = s3 + 3 * var_in * s1  # Σ box·E[ε³]
    c0 = two_d * s1 + b2
    c1 = two_d * b2 + e3
    c2 = two_d * e3 + s4 + 6 * var_in * moments[2] + 1.8 * var_in**2 * s0
    return c0[:, :, None] * f + c1[:, :, None] * df + 0.5 * c2[:, :, None] * d2f


def pair_offsets_mm(grid: AxisGrid) -> np.ndarray:
    """``(n_sensor, n_scene)`` centre offsets ``s - u`` of every pixel pair (mm)."""
    return grid.scene_centres_mm()[None, :] - grid.sensor_centres_mm()[:, None]


def _r2_nodes(d2_lo: float, d2_hi: float, tables: RefractedTables, reach_mm: float,
              width_mm: float, step_um: float = CROSSING_STEP_UM) -> np.ndarray:
    """Uniform ``D²`` nodes over ``[d2_lo, d2_hi]``: the crossing ``dx·κ`` moves by at most
    ``min(step_um, width/10)`` per step for offsets up to ``reach_mm``."""
    probe = np.linspace(0.0, reach_mm**2 + d2_hi, 512)
    slope = float(np.max(np.abs(tables.kappa.d1(probe)))) * reach_mm  # |d(dx·κ)/dD²|
    step_move = min(step_um * 1e-3, width_mm / 10)
    span = d2_hi - d2_lo
    n_int = max(3, int(math.ceil(span * max(slope, 1e-12) / step_move)))
    if span <= 0:
        return d2_lo + np.arange(4) * 1e-6
    # the cubic interpolation takes one-sided stencils at the ends (no node below D² = 0,
    # where κ(ρ²) is not defined)
    return np.linspace(d2_lo, d2_hi, n_int + 1)


def refracted_terms(
    kp: KernelParams, exp: SeparableExpansion, tables: RefractedTables,
    profiles_x: tuple[np.ndarray, np.ndarray], profiles_y: tuple[np.ndarray, np.ndarray],
    pairs: list[tuple[str, int, float]],
) -> list[SeparableTerm]:
    """Separable terms ``Σ coef·A_v(m_x)·B_v(m_y)`` along the refracted crossing map.

    The x-matrices ``X(D_y²)`` are taken at the y pair's centre offset; the first-order
    correction for ``δ_y²`` varying across the y pair, ``∂X/∂D²·(δ_y² - D_y²)``, is one more
    separable product: the x family's derivative (the derivative of its interpolated weights)
    times the y-matrices weighted by ``δ_y² - D_y²`` (``refracted_axis_family(...,
    weighted=True)``); likewise for y. At ~20° offsets in both axes this removes a ±0.5 µm
    drift of the crossing across a pair (0.5 % on such pairs before).

    Parameters
    ----------
    kp
        Kernel parameters (grids, shift ``dx_um``/``dy_um``, ``n_sub``).
    exp
        The separable expansion of the refracted radial factor.
    tables
        ``κ`` and ``F`` splines.
    profiles_x, profiles_y
        ``(edges (J+1,), values (V, J))`` of the one-axis profiles (mm).
    pairs
        ``(part, v, coef)`` as in :func:`thintact_sdk.simulation.rotated.rotated_terms`.
    """
    gx, gy = kp.grid_x(), kp.grid_y()
    ox, oy = pair_offsets_mm(gx), pair_offsets_mm(gy)  # (S, M), (R, N)
    k0 = float(tables.kappa.value(np.array(0.0)))
    families = []
    for grid, prof, derivs, other, shift in (
            (gx, profiles_x, exp.fx_derivs, oy, kp.dx_um * 1e-3),
            (gy, profiles_y, exp.gy_derivs, ox, kp.dy_um * 1e-3)):
        o2 = other**2
        reach = grid.max_offset_mm()
        width = min((1 - k0) * grid.sensor_pitch_mm, k0 * grid.scene_pitch_mm)
        nodes = _r2_nodes(float(o2.min()), float(o2.max()), tables, reach, width)
        _check_family_size(grid, 2 * nodes.size, prof[1].shape[0], exp.rank)
        fam = refracted_axis_family(grid, prof[0], prof[1], derivs, tables.kappa, nodes,
                                    kp.n_sub, shift, weighted=True)
        families.append(_CoupledFamily.build(
            fam, np.gradient(fam[0], nodes, axis=0, edge_order=2), float(np.ptp(nodes)),
            FAMILY_RANK_TOL,
            partial(interp_weights_1d, nodes, t=o2)))
        del fam
    fx, fy = families
    terms: list[SeparableTerm] = []
    for part, v, coef in pairs:
        if coef == 0:
            continue
        terms += compress_terms(_main_products(fx, fy, v, coef, part, exp.rank),
                                kp.compress_tol / 4)
        terms += compress_terms(_correction_products(fx, fy, v, coef, part, exp.rank),
                                CORRECTION_COMPRESS_TOL)
    return compress_terms(terms, kp.compress_tol)


class _CoupledFamily:
    """One axis's compressed families, their weights read at every pair of the other axis:
    ``X(D²) = Σ_j u_j(D²)·B_j``, its derivative ``∂X/∂D² = Σ_j du_j(D²)·dB_j`` and the
    ``(δ² - D²)``-weighted family ``Σ_j w_j(D²)·C_j``.

    ``u``: ``(V, r) + other pairs``; ``basis``: ``(V, r, L) + this axis's pairs`` (ranks per
    profile ``ranks``); likewise ``du, dbasis, dranks`` and ``w, basis1, ranks1``.
    """

    def __init__(self, parts: list[tuple[np.ndarray, np.ndarray, list[int]]]) -> None:
        (self.u, self.basis, self.ranks), (self.du, self.dbasis, self.dranks), \
            (self.w, self.basis1, self.ranks1) = parts

    @classmethod
    def build(cls, fam: np.ndarray, dfam: np.ndarray, span: float, tol: float,
              interp: Callable[[np.ndarray], np.ndarray],
              corr_rel: np.ndarray | None = None,
              norms: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> _CoupledFamily:
        """From the tabulated ``(2, T, V, ...)`` plain and weighted families and the plain
        family's ``D²`` derivative ``(T, V, ...)`` over a node range ``span`` (mm²): compress
        each over the nodes and ``interp`` their weights ``(V, T, r)`` at the other axis's
        pairs. The plain family is cut at ``tol``; the weighted one at ``corr_rel`` (one per
        profile; default :data:`CORRECTION_RANK_TOL`) of its norm; the derivative at ``tol``
        of the plain family's norm over ``span`` (a relative cut of a family that hardly
        moves would keep its rounding noise), or, when ``corr_rel`` is given, at ``corr_rel``
        of its own norm where that is larger.
        ``norms``: the three families' :func:`family_norms` when already computed."""
        parts = []
        n0, nd, n1 = family_norms(fam, dfam) if norms is None else norms
        weights, basis, ranks = compress_family(fam[0], tol)
        parts.append((interp(weights), basis, ranks))
        rel = np.full(fam.shape[2], CORRECTION_RANK_TOL) if corr_rel is None else corr_rel
        cut = tol * n0 / max(span, 1e-12)
        if corr_rel is not None:
            cut = np.maximum(cut, corr_rel * nd)
        weights, basis, ranks = compress_family(dfam, abs_cut=cut)
        parts.append((interp(weights), basis, ranks))
        weights, basis, ranks = compress_family(fam[1], abs_cut=rel * n1)
        parts.append((interp(weights), basis, ranks))
        return cls(parts)


def family_norms(fam: np.ndarray, dfam: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(V,)`` Frobenius norms per profile of the plain and weighted families
    (``fam``: ``(2, T, V, ...)``) and of the derivative ``dfam`` ``(T, V, ...)``:
    ``(|X|, |∂X/∂D²|, |X₁|)``."""
    def per_v(a: np.ndarray) -> np.ndarray:
        flat = a.reshape(a.shape[0], a.shape[1], -1)
        return np.sqrt(np.einsum("tvk,tvk->v", flat, flat))
    return per_v(fam[0]), per_v(dfam), per_v(fam[1])


def correction_size(norms_x: tuple[np.ndarray, np.ndarray, np.ndarray],
                    norms_y: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """``(V,)`` estimated size of the first-order coupling correction relative to the kernel,
    per profile: ``|∂X/∂D²|/|X|·|Y₁|/|Y| + |X₁|/|X|·|∂Y/∂D²|/|Y|`` from each axis's
    :func:`family_norms`. 1.5e-3 on the 16×20 test window at ~21° offsets, 1.8e-4 on
    golden-mini (an upper estimate: the correction measured there changes the frames by
    3e-6)."""
    (x0, xd, x1), (y0, yd, y1) = norms_x, norms_y
    x0, y0 = np.maximum(x0, 1e-300), np.maximum(y0, 1e-300)
    return np.asarray(xd / x0 * y1 / y0 + x1 / x0 * yd / y0)


def _main_products(fx: _CoupledFamily, fy: _CoupledFamily, v: int, coef: float, part: str,
                   rank: int, j_only: int | None = None) -> list[SeparableTerm]:
    """The products ``(y side) ⊗ (x side)`` ``X(D_y²)·Y(D_x²)`` of profile ``v`` (for one x
    basis index ``j_only`` if given)."""
    js = range(fx.ranks[v]) if j_only is None else [j_only]
    return [SeparableTerm(coef * fx.u[v, j] * fy.basis[v, i, ll],
                          fx.basis[v, j, ll] * fy.u[v, i], part)
            for ll in range(rank) for j in js for i in range(fy.ranks[v])]


def _correction_products(fx: _CoupledFamily, fy: _CoupledFamily, v: int, coef: float,
                         part: str, rank: int) -> list[SeparableTerm]:
    """The first-order coupling corrections of profile ``v``: ``∂X/∂D²·Y₁ + X₁·∂Y/∂D²``
    (``Y₁``: the y family weighted by ``δ_y² - D_y²``)."""
    out = [SeparableTerm(coef * fx.du[v, j] * fy.basis1[v, i, ll],
                         fx.dbasis[v, j, ll] * fy.w[v, i], part)
           for ll in range(rank) for j in range(fx.dranks[v]) for i in range(fy.ranks1[v])]
    out += [SeparableTerm(coef * fx.w[v, j] * fy.dbasis[v, i, ll],
                          fx.basis1[v, j, ll] * fy.du[v, i], part)
            for ll in range(rank) for j in range(fx.ranks1[v]) for i in range(fy.dranks[v])]
    return out


def _compress_main_products(fx: _CoupledFamily, fy: _CoupledFamily, v: int, coef: float,
                            part: str, rank: int, tol: float, js: list[int]) -> list[SeparableTerm]:
    """The main products of profile ``v`` for the x basis indices ``js``, compressed one x
    basis matrix at a time (relative cut ``tol``) and merged once the list has doubled since
    the last merge (with ~270 terms kept per merge, merging at a fixed 300 recompressed ~320
    terms after every block)."""
    acc: list[SeparableTerm] = []
    merge_at = MERGE_TERMS
    for j in js:
        acc += compress_terms(_main_products(fx, fy, v, coef, part, rank, j_only=j), tol)
        if len(acc) > merge_at:
            acc = compress_terms(acc, tol)
            merge_at = max(MERGE_TERMS, 2 * len(acc))
    return acc


def _lagrange4(nodes: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """First index and the four cubic Lagrange weights of uniform ``nodes`` at ``t``."""
    n = nodes.size
    pos = np.clip((t - nodes[0]) / (nodes[1] - nodes[0]), 0.0, n - 1.000001)
    base = np.clip(np.floor(pos).astype(np.int64) - 1, 0, n - 4)
    x = pos - base
    ls = []
    for k in range(4):
        lk = np.ones_like(x)
        for j in range(4):
            if j != k:
                lk = lk * (x - j) / (k - j)
        ls.append(lk)
    return base, ls


def interp_weights_1d(nodes: np.ndarray, weights: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``(V, r) + t.shape``: weights ``(V, T, r)`` tabulated on uniform ``nodes`` (``T`` ≥ 4),
    interpolated by local cubics at ``t``."""
    b, ls = _lagrange4(nodes, t)
    out = np.zeros(weights.shape[:1] + t.shape + weights.shape[2:])
    for k in range(4):
        out += weights[:, b + k] * ls[k][None, ..., None]
    return np.moveaxis(out, -1, 1)


def interp_weights_2d(nodes1: np.ndarray, nodes2: np.ndarray, weights: np.ndarray,
                      t1: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """``(V, r) + t1.shape``: weights ``(V, T1·T2, r)`` tabulated on the product grid of two
    uniform node sets (``T1``, ``T2`` ≥ 4), bicubically interpolated at ``(t1, t2)``."""
    n_v, _, r = weights.shape
    w = weights.reshape(n_v, nodes1.size, nodes2.size, r)
    b1, l1 = _lagrange4(nodes1, t1)
    b2, l2 = _lagrange4(nodes2, t2)
    out = np.zeros((n_v,) + t1.shape + (r,))
    for a in range(4):
        for b in range(4):
            out += w[:, b1 + a, b2 + b] * (l1[a] * l2[b])[None, ..., None]
    return np.moveaxis(out, -1, 1)


def _shift_nodes(t_lo: float, t_hi: float, width_mm: float) -> np.ndarray:
    """Uniform displacement nodes (≥ 4) over ``[t_lo, t_hi]``, step ≤ ``SHIFT_STEP_UM`` and a
    tenth of the narrower trapezoid width (as for the rotated mask)."""
    step = min(SHIFT_STEP_UM * 1e-3, width_mm / SHIFT_STEPS_PER_WIDTH)
    n_int = max(3, int(math.ceil((t_hi - t_lo) / step)))
    if t_hi <= t_lo:
        return t_lo + (np.arange(4) - 1.5) * step
    return np.linspace(t_lo, t_hi, n_int + 1)


def refracted_rotated_terms(
    kp: KernelParams, exp: SeparableExpansion, tables: RefractedTables,
    profiles_x: tuple[np.ndarray, np.ndarray], profiles_y: tuple[np.ndarray, np.ndarray],
    pairs: list[tuple[str, int, float]],
) -> list[SeparableTerm]:
    """:func:`refracted_terms` for a rotated mask: the pattern-frame profiles are read at
    ``p_x = c·(m_x - dx) + t_x``, ``p_y = c·(m_y - dy) - t_y`` with the coupling frozen at
    the pair's centre crossing point (``t_x = s·(M_y - dy)``, ``t_y = s·(M_x - dx)``, as in
    :mod:`~thintact_sdk.simulation.rotated`; ``M`` taken with the other axis's offset set to
    zero inside ``κ``, which moves it by ``s·D·Δκ``, well under 0.1 µm at the angles a
    misalignment has). The x family then depends on the y pair through two numbers,
    ``(D_y², t_x)``: it is tabulated on their product grid, compressed by one SVD and its
    weights interpolated bicubically; likewise for y. The first-order coupling correction of
    :func:`refracted_terms` is added with its factors cut to the error budget
    :data:`CORRECTION_ERROR` (:func:`correction_size`). The two axes are tabulated, and at
    large angles the product blocks compressed, on the build threads
    (:mod:`~thintact_sdk.host.build_threads`)."""
    a = math.radians(kp.angle_deg)
    c, s = math.cos(a), math.sin(a)
    sx_mm, sy_mm = kp.dx_um * 1e-3, kp.dy_um * 1e-3
    gx, gy = kp.grid_x(), kp.grid_y()
    ox, oy = pair_offsets_mm(gx), pair_offsets_mm(gy)
    k0 = float(tables.kappa.value(np.array(0.0)))
    cross_x = gx.sensor_centres_mm()[:, None] + ox * tables.kappa.value(ox**2)  # (S, M)
    cross_y = gy.sensor_centres_mm()[:, None] + oy * tables.kappa.value(oy**2)  # (R, N)
    # x profile read at m - (dx - t_x/c) after scaling its edges by 1/c; y at m - (dy + t_y/c)
    disp_x = sx_mm - s * (cross_y - sy_mm) / c  # (R, N): a function of the y pair
    disp_y = sy_mm + s * (cross_x - sx_mm) / c  # (S, M): a function of the x pair
    def tabulate(axis: tuple[AxisGrid, tuple[np.ndarray, np.ndarray], FactorDerivs, np.ndarray,
                             np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                   Callable[[np.ndarray], np.ndarray]]:
        grid, prof, derivs, other, disp = axis
        o2 = other**2
        width = min((1 - k0) * grid.sensor_pitch_mm, k0 * grid.scene_pitch_mm)
        n_r2 = _r2_nodes(float(o2.min()), float(o2.max()), tables, grid.max_offset_mm(), width)
        n_sh = _shift_nodes(float(disp.min()), float(disp.max()), width)
        _check_family_size(grid, 3 * n_r2.size * n_sh.size, prof[1].shape[0], exp.rank)
        fam = refracted_axis_family(grid, prof[0] / c, prof[1], derivs, tables.kappa, n_r2,
                                    kp.n_sub, n_sh, weighted=True)  # (2, T1, T2, V, L, r, n)
        dfam = np.gradient(fam[0], n_r2, axis=0, edge_order=2)
        flat = (2, n_r2.size * n_sh.size) + fam.shape[3:]
        return (fam.reshape(flat), dfam.reshape(flat[1:]), n_r2,
                partial(interp_weights_2d, n_r2, n_sh, t1=o2, t2=disp))

    # the two axes are independent: tabulated side by side (build_threads)
    tabulated = thread_map(tabulate, [(gx, profiles_x, exp.fx_derivs, oy, disp_x),
                                      (gy, profiles_y, exp.gy_derivs, ox, disp_y)])
    norms = [family_norms(fam, dfam) for fam, dfam, _, _ in tabulated]
    corr_rel = np.clip(CORRECTION_ERROR / np.maximum(correction_size(*norms), 1e-300),
                       CORRECTION_RANK_TOL, 0.5)
    families = [_CoupledFamily.build(fam, dfam, float(np.ptp(nodes)), SHIFT_RANK_TOL, interp,
                                     corr_rel, nrm)
                for (fam, dfam, nodes, interp), nrm in zip(tabulated, norms, strict=True)]
    del tabulated
    fx, fy = families
    terms: list[SeparableTerm] = []
    for part, v, coef in pairs:
        if coef == 0:
            continue
        terms += compress_terms(_correction_products(fx, fy, v, coef, part, exp.rank),
                                float(max(CORRECTION_COMPRESS_TOL, corr_rel[v])))
        if exp.rank * fx.ranks[v] * fy.ranks[v] <= ONE_SHOT_TERMS:
            terms += compress_terms(_main_products(fx, fy, v, coef, part, exp.rank),
                                    kp.compress_tol / 4)
            continue
        # large angles: the two-parameter families have high ranks, so the r_x·r_y·L products
        # are compressed one x basis matrix at a time and merged (bounded memory, slower), the
        # x basis matrices dealt round-robin to the build threads (independent until the end)
        n_groups = build_threads()
        groups = [list(range(fx.ranks[v]))[k::n_groups] for k in range(n_groups)]
        merged = thread_map(partial(_compress_main_products, fx, fy, v, coef, part, exp.rank,
                                    kp.compress_tol / 8), [g for g in groups if g])
        terms += compress_terms([t for acc in merged for t in acc], kp.compress_tol / 4)
    return compress_terms(terms, kp.compress_tol)


def _reach_mm(kp: KernelParams) -> tuple[float, float]:
    """Largest pair offsets per axis (mm) plus a margin of two pixels: what the tables cover."""
    margin = 2 * max(kp.pitch_um, kp.scene_pitch_um) * 1e-3
    return kp.grid_x().max_offset_mm() + margin, kp.grid_y().max_offset_mm() + margin


def _refracted_tables(kp: KernelParams, reach_mm: tuple[float, float] | None = None
                      ) -> RefractedTables:
    """The refracted map's radial tables over every pair offset of ``kp`` (``reach_mm``:
    :func:`_reach_mm`, when the caller has it)."""
    hx, hy = reach_mm or _reach_mm(kp)
    return RefractedTables(kp.z_mm, kp.d_mm, kp.n_scene_side, kp.q - 4.0, math.hypot(hx, hy))


def _tables_and_expansion(kp: KernelParams) -> tuple[RefractedTables, SeparableExpansion]:
    hx, hy = _reach_mm(kp)
    tables = _refracted_tables(kp, (hx, hy))
    exp = SeparableExpansion.build(kp.z_mm + kp.d_mm, kp.q, hx, hy, rel_tol=kp.rank_tol,
                                   radial=tables.factor)
    return tables, exp


def build_refracted_kernel(kp: KernelParams) -> SeparableKernel:
    """The separable kernel of a (possibly rotated) mask behind a refracting scene gap,
    geometric or with diffraction (one set of terms per distinct wavelength)."""
    tables, exp = _tables_and_expansion(kp)
    make = refracted_rotated_terms if kp.angle_deg != 0.0 else refracted_terms
    info = {"rank": float(exp.rank), "radiometric_rel_error": exp.rel_error}
    k = len(kp.phi)
    edges = mask_cell_edges_mm(k, kp.feature_um * 1e-3)
    if kp.wavelengths_nm is None:
        c_o, c_c = mask_leakage.intensity_coefficients(kp.leakage)
        px = (edges, np.stack([np.ones(k), np.asarray(kp.phi, float)]))
        py = (edges, np.stack([np.ones(k), np.asarray(kp.phi_rows, float)]))
        terms = make(kp, exp, tables, px, py, [("open", 0, c_o), ("coding", 1, c_c)])
        info["terms"] = float(len(terms))
        return SeparableKernel([terms] * kp.channels, info)
    a_o, a_c = mask_leakage.amplitude_coefficients(kp.leakage)
    pairs = [("open", 0, a_o**2), ("open", 1, a_c**2), ("coding", 2, 2 * a_o * a_c),
             ("coding", 3, -2 * a_o * a_c)]
    z_eff = kp.z_mm / kp.n_scene_side  # the spherical wave's curvature in the medium
    k_max = float(np.max(tables.kappa.value(np.linspace(0, exp.x_nodes.max()**2
                                                        + exp.y_nodes.max()**2, 64))))
    # crossing points in the pattern frame: rotation mixes in the other axis's extent
    sin_a = abs(math.sin(math.radians(kp.angle_deg)))
    half = max(g.n_sensor * g.sensor_pitch_mm / 2 + k_max * g.max_offset_mm()
               for g in (kp.grid_x(), kp.grid_y()))

    def build(lam: float) -> list[SeparableTerm]:
        profs = []
        for grid, phi in ((kp.grid_x(), kp.phi), (kp.grid_y(), kp.phi_rows)):
            reach = half * (1 + sin_a) + (abs(kp.dx_um) + abs(kp.dy_um)) * 1e-3 \
                + 4 * grid.sensor_pitch_mm + 4 * grid.scene_pitch_mm
            profs.append(diffraction.axis_intensity_profiles(
                edges, np.asarray(phi, float), -reach, reach, lam, z_eff, kp.d_mm))
        return make(kp, exp, tables, profs[0], profs[1], pairs)

    per_channel = per_channel_by_wavelength(kp.wavelengths_nm, kp.channels, build)
    info["terms"] = float(max(len(t) for t in per_channel))
    return SeparableKernel(per_channel, info)
