"""``diffraction``: the mask is a thin amplitude screen lit by a spherical wave from each
scene point; Fresnel propagation to the sensor in air.

For a scene point ``s`` and sensor point ``u`` (one axis) the Fresnel phase
``π/λ·[(m - s)²/z + (u - m)²/d]`` equals ``π·(m - m*)²/w² + const`` with
``m* = (z·u + d·s)/H`` the geometric crossing point and ``w² = λ·z·d/H``. The field
behind a 1-D profile ``A`` is therefore a function of ``m*`` only::

    V_A(m*) = e^{-iπ/4}/sqrt(2) · Σ_j A_j [E(t_{j+1}) - E(t_j)],  t = sqrt(2)(e - m*)/w

with ``E = C + iS`` the Fresnel integrals (``V = 1`` for an unbounded open profile). A
separable amplitude mask ``c_o·a⊗a + c_c·φ⊗φ`` gives the intensity
``c_o²|V_a|²⊗|V_a|² + c_c²|V_φ|²⊗|V_φ|² + 2c_o·c_c(Re⊗Re - Im⊗Im)`` of ``V_a·conj(V_φ)`` per
axis: four separable terms per wavelength. As λ → 0 this tends to the geometric shadow.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.special import fresnel

from thintact_sdk.errors import KernelSizeError
from thintact_sdk.simulation.effects._spec import (
    DeviceProfile,
    EffectSpec,
    FitSpec,
    Params,
    ParamSpec,
    const,
)


def fresnel_width_mm(wavelength_nm: float, z_mm: float, d_mm: float) -> float:
    """``w = sqrt(λ·z·d/H)`` in mm: the lateral scale of the diffraction fringes."""
    return math.sqrt(wavelength_nm * 1e-6 * z_mm * d_mm / (z_mm + d_mm))


def axis_fields(
    cell_edges_mm: np.ndarray, profiles: np.ndarray, m_mm: np.ndarray, w_mm: float,
    chunk: int = 2048,
) -> np.ndarray:
    """Complex fields ``V_A(m*)`` of piecewise-constant profiles.

    Parameters
    ----------
    cell_edges_mm
        ``(K+1,)`` cell edges.
    profiles
        ``(V, K)`` cell values (zero outside the mask).
    m_mm
        ``(J,)`` geometric crossing points ``m*``.
    w_mm
        Fresnel width (see :func:`fresnel_width_mm`).

    Returns
    -------
    numpy.ndarray
        ``(V, J)`` complex fields (1 for an unbounded open profile).
    """
    n_v, k = profiles.shape
    ext = np.zeros((n_v, k + 2))
    ext[:, 1:-1] = profiles
    jumps = ext[:, :-1] - ext[:, 1:]  # (V, K+1): A_{i-1} - A_i at edge i
    out = np.empty((n_v, m_mm.size), complex)
    pref = np.exp(-1j * math.pi / 4) / math.sqrt(2)
    for j0 in range(0, m_mm.size, chunk):
        mm = m_mm[j0:j0 + chunk]
        t = math.sqrt(2) * (cell_edges_mm[None, :] - mm[:, None]) / w_mm
        s, c = fresnel(t)
        e = c + 1j * s  # (J, K+1)
        out[:, j0:j0 + chunk] = pref * (e @ jumps.T).T
    return out


def axis_fields_local(
    cell_edges_mm: np.ndarray, profiles: np.ndarray, m_mm: np.ndarray, w_mm: float,
    reach_w: float = 48.0, chunk: int = 2048,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`axis_fields` with the edges farther than ``reach_w·w`` replaced by their
    geometric limit ``E(±inf) = ±(1+i)/2``, plus the mean power of what was dropped.

    A far edge at distance ``x`` adds fringes of period ``w²/x`` (finer than ``w/reach_w``),
    which average out over any pixel but would alias in point samples. Their mean power is
    kept: ``|E(t) - E(±inf)|² ≈ 1/(π²t²)``, so profiles ``a``, ``b`` gain
    ``Σ_far jump_a·jump_b · w²/(4π²x²)`` in ``⟨V_a conj(V_b)⟩`` (same edge, same phase).

    Returns
    -------
    fields
        ``(V, J)`` complex fields without the far fringes.
    tail_power
        ``(V, V, J)`` mean power of the dropped fringes for each pair of profiles.
    """
    n_v, k = profiles.shape
    ext = np.zeros((n_v, k + 2))
    ext[:, 1:-1] = profiles
    jumps = ext[:, :-1] - ext[:, 1:]  # (V, K+1)
    cum = np.zeros((n_v, k + 2))
    cum[:, 1:] = np.cumsum(jumps, axis=1)  # cum[:, j] = Σ_{i<j} jump_i
    reach = reach_w * w_mm
    n_win = int(math.ceil(2 * reach / float(np.min(np.diff(cell_edges_mm))))) + 2
    pref = np.exp(-1j * math.pi / 4) / math.sqrt(2)
    half = (1 + 1j) / 2
    out = np.empty((n_v, m_mm.size), complex)
    tail = np.empty((n_v, n_v, m_mm.size))
    pair = jumps[:, None, :] * jumps[None, :, :]  # (V, V, K+1)
    for j0 in range(0, m_mm.size, chunk):
        mm = m_mm[j0:j0 + chunk]
        dist = cell_edges_mm[None, :] - mm[:, None]  # (J, K+1)
        far_edge = np.abs(dist) >= reach
        inv2 = np.where(far_edge, w_mm**2 / (4 * math.pi**2) / np.where(far_edge, dist, 1.0) ** 2,
                        0.0)
        tail[:, :, j0:j0 + chunk] = np.einsum("abk,jk->abj", pair, inv2)
        lo = np.searchsorted(cell_edges_mm, mm - reach)
        hi = np.searchsorted(cell_edges_mm, mm + reach)
        far = half * (cum[:, -1][:, None] - cum[:, hi] - cum[:, lo])  # (V, J)
        idx = lo[:, None] + np.arange(n_win)[None, :]
        valid = idx < hi[:, None]
        idx_c = np.minimum(idx, k)
        t = math.sqrt(2) * (cell_edges_mm[idx_c] - mm[:, None]) / w_mm
        s_, c_ = fresnel(t)
        e = np.where(valid, c_ + 1j * s_, 0.0)  # (J, n_win)
        near = np.einsum("jw,vjw->vj", e, jumps[:, idx_c])
        out[:, j0:j0 + chunk] = pref * (near + far)
    return out, tail


def lattice_fields(
    first_edge_mm: float, pitch_mm: float, profiles: np.ndarray, sub: int, k_lo: int, k_hi: int,
    w_mm: float, reach_w: float = 48.0,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`axis_fields_local` for cells of equal width, at points on a finer lattice.

    The mask edges are ``e_j = first_edge_mm + j·pitch_mm`` and the points are the centres
    ``first_edge_mm + (k + 1/2)·h`` of the fine cells ``k_lo ≤ k < k_hi``, ``h = pitch_mm/sub``.
    Every edge-to-point distance is then ``(j·sub - k - 1/2)·h``: the windowed Fresnel
    function (exact within ``reach_w·w``, its geometric limit ``±(1+i)/2`` beyond) and the
    dropped fringes' mean power are tabulated once on that lattice, and the sums over edges
    become correlations of the (upsampled) edge jumps with the tables, done by FFT: about
    ``2·reach_w·w/h`` Fresnel integrals instead of one per (point, near edge).

    Parameters
    ----------
    first_edge_mm, pitch_mm
        First mask edge and the cell width (mm).
    profiles
        ``(V, K)`` cell values (zero outside the mask).
    sub
        Fine cells per mask cell.
    k_lo, k_hi
        Fine cell indices (relative to the first edge; may be negative or beyond ``K·sub``).
    w_mm, reach_w
        Fresnel width and the reach of the exact part (see :func:`axis_fields_local`).

    Returns
    -------
    fields
        ``(V, k_hi - k_lo)`` complex fields without the far fringes.
    tail_power
        ``(V, V, k_hi - k_lo)`` mean power of the dropped fringes per pair of profiles.
    """
    from scipy.signal import fftconvolve

    n_v, k = profiles.shape
    ext = np.zeros((n_v, k + 2))
    ext[:, 1:-1] = profiles
    jumps = ext[:, :-1] - ext[:, 1:]  # (V, K+1): A_{j-1} - A_j at edge j
    h = pitch_mm / sub
    # distances (n - k - 1/2)·h for n = j·sub: n - k runs over lag = n_min .. n_max
    lag_lo, lag_hi = -(k_hi - 1), k * sub - k_lo
    x = (np.arange(lag_lo, lag_hi + 1) - 0.5) * h
    reach = reach_w * w_mm
    near = np.abs(x) < reach
    g = np.where(x > 0, 0.5 + 0.5j, -0.5 - 0.5j).astype(complex)
    s_, c_ = fresnel(math.sqrt(2) * x[near] / w_mm)
    g[near] = c_ + 1j * s_
    far_power = np.where(near, 0.0, w_mm**2 / (4 * math.pi**2) / np.where(near, 1.0, x) ** 2)
    up = np.zeros((n_v, k * sub + 1))
    up[:, ::sub] = jumps  # jumps at n = j·sub
    # c[k] = Σ_n up[n]·g[n - k - lag_lo]: a correlation, i.e. a convolution with the
    # flipped table (:func:`_correlation_window`)
    n_out = k_hi - k_lo
    pref = np.exp(-1j * math.pi / 4) / math.sqrt(2)
    fields = np.empty((n_v, n_out), complex)
    for v in range(n_v):
        full = fftconvolve(up[v], g[::-1])
        fields[v] = pref * _correlation_window(full, g.size, lag_lo, k_lo, n_out)
    tail = np.empty((n_v, n_v, n_out))
    for a in range(n_v):
        for b in range(a, n_v):
            full = fftconvolve(up[a] * up[b], far_power[::-1])
            tail[a, b] = tail[b, a] = _correlation_window(full, far_power.size, lag_lo, k_lo, n_out)
    return fields, tail


def _correlation_window(full: np.ndarray, n_table: int, lag_lo: int, k_lo: int,
                        n_out: int) -> np.ndarray:
    """Pick ``c[k] = Σ_n up[n]·table[n - k - lag_lo]`` for ``k = k_lo .. k_lo + n_out - 1``
    out of ``full = up * table[::-1]`` (full convolution): ``c[k] = full[n_table - 1 + lag_lo + k]``."""
    start = n_table - 1 + lag_lo + k_lo
    return full[start:start + n_out]


def axis_intensity_profiles(
    cell_edges_mm: np.ndarray, phi: np.ndarray, m_lo_mm: float, m_hi_mm: float,
    wavelength_nm: float, z_mm: float, d_mm: float, reach_w: float = 48.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Fine piecewise-constant profiles ``|V_a|², |V_φ|², Re, Im of V_a·conj(V_φ)``.

    Parameters
    ----------
    cell_edges_mm, phi
        ``(K+1,)`` cell edges and ``(K,)`` ±1 values along this axis.
    m_lo_mm, m_hi_mm
        Range of crossing points the device uses.
    wavelength_nm, z_mm, d_mm
        Wavelength and distances.
    reach_w
        Edges within ``reach_w·w`` are diffracted exactly; farther ones contribute their
        geometric limit plus the mean power of their fringes (:func:`axis_fields_local`).
        Against box-averaged exact fields (10 µm pixels, virtual-mini geometry) the error is
        below 1e-4 for 48 and 4e-4 for 32.

    Returns
    -------
    edges
        ``(J+1,)`` fine cell edges (mm), step ≤ w/(4·reach_w) (the finest kept fringe
        sampled four times per period) and ≤ δ/8. With cells of equal width the fine cells
        subdivide them (an integer number per cell, aligned with the mask edges) and the
        fields come from :func:`lattice_fields`; otherwise from :func:`axis_fields_local`.
    values
        ``(4, J)`` profile values at the fine cell centres (fields without the fringes
        finer than the step, which would alias, plus their mean power).
    """
    w = fresnel_width_mm(wavelength_nm, z_mm, d_mm)
    widths = np.diff(cell_edges_mm)
    feature = float(np.min(widths))
    step = min(w / (4 * reach_w), feature / 8)
    samples = (m_hi_mm - m_lo_mm) / step
    if samples > MAX_AXIS_SAMPLES:
        raise KernelSizeError(
            f"physics.diffraction: at {wavelength_nm:g} nm the fringes are {w * 1e3:.3g} um wide and "
            f"the mask would be sampled at {samples:.3g} points along an axis (at most "
            f"{MAX_AXIS_SAMPLES:.0e}): a wavelength this short is geometric optics, leave the effect out")
    profiles = np.stack([np.ones_like(phi, dtype=float), np.asarray(phi, float)])
    if np.allclose(widths, widths[0], rtol=1e-9, atol=0.0):
        sub = int(math.ceil(feature / step))
        h = feature / sub
        e0 = float(cell_edges_mm[0])
        k_lo = int(math.floor((m_lo_mm - e0) / h)) - 1
        k_hi = int(math.ceil((m_hi_mm - e0) / h)) + 1
        edges = e0 + np.arange(k_lo, k_hi + 1) * h
        (va, vp), tail = lattice_fields(e0, feature, profiles, sub, k_lo, k_hi, w, reach_w)
    else:
        n = int(math.ceil((m_hi_mm - m_lo_mm) / step)) + 2
        edges = m_lo_mm - step + np.arange(n + 1) * step
        centres = (edges[1:] + edges[:-1]) / 2
        (va, vp), tail = axis_fields_local(cell_edges_mm, profiles, centres, w, reach_w)
    cross = va * np.conj(vp)
    values = np.stack([np.abs(va) ** 2 + tail[0, 0], np.abs(vp) ** 2 + tail[1, 1],
                       cross.real + tail[0, 1], cross.imag])
    return edges, values


DEFAULT_WAVELENGTHS_NM = (625.0, 530.0, 465.0)


def _to_params(v: np.ndarray, _p: DeviceProfile) -> dict[str, Any]:
    return {"wavelength_nm": [round(float(x), 2) for x in v]}


def _from_params(d: Params, _p: DeviceProfile) -> np.ndarray:
    wl = d["wavelength_nm"]
    return np.asarray(wl if isinstance(wl, list) else [wl] * 3, np.float64)


def describe(params: Params, p: DeviceProfile) -> str:
    """The finding in words."""
    d_mm = p.geometry.mask_to_sensor_mm
    wl = [float(x) for x in params["wavelength_nm"]]
    blur = [math.sqrt(w * 1e-6 * d_mm) * 1e3 for w in wl]
    return (
        f"Fresnel diffraction at the mask: with wavelengths {', '.join(f'{w:.0f}' for w in wl)} nm "
        f"the {p.mask.feature_um:g} um cells blur by about {min(blur):.0f}-{max(blur):.0f} um "
        f"(sqrt(λ·d)) over the {d_mm:g} mm gap; the model assumed sharp geometric shadows."
    )


MAX_AXIS_SAMPLES = 1e6
"""Most fine samples along one mask axis the Fresnel profiles may take: a 0.001 nm wavelength
on a 1.3 mm mask asked for about 1e6 and its convolutions ran for minutes or ended in
std::bad_alloc; the 2 nm of the geometric-limit tests takes about 2e4, visible light a few
hundred."""


SPEC = EffectSpec(
    name="diffraction",
    stage="kernel",
    description="light bends at the mask cell edges (wave optics, Fresnel), per colour",
    params={
        "wavelength_nm": ParamSpec("nm", list(DEFAULT_WAVELENGTHS_NM), (1e-3, 2000.0),
                                   "centre wavelength of the R, G, B channels", shape=(3,))
    },
    kernel=lambda params, _p: {"wavelengths_nm": tuple(params["wavelength_nm"])},
    describe=describe,
    fit=FitSpec(
        # null 0 nm: the geometric-optics limit (the effect absent)
        "optical", ("wavelength_nm R", "wavelength_nm G", "wavelength_nm B"), const(0.0, 0.0, 0.0),
        const(*DEFAULT_WAVELENGTHS_NM), _to_params, _from_params, channelwise=True,
        signed=(False, False, False),
    ),
)
