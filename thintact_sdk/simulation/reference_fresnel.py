"""Brute-force reference of the ``diffraction`` kernel (tiny devices only; tests and tools).

The contract's definition (CONTRACTS §4, §5 ``diffraction``) evaluated directly, sharing no
code with the simulator's diffraction path (:mod:`thintact_sdk.simulation.effects.diffraction`,
:mod:`~thintact_sdk.simulation.rotated`, :mod:`~thintact_sdk.simulation.refracted`):

- every sensor pixel and every scene pixel is sub-sampled with ``n × n`` Gauss-Legendre
  points (or midpoints); every (sensor point ``u``, scene point ``s``) pair is one ray;
- the scene point's spherical wave, Fresnel-propagated through the mask (a thin amplitude
  screen: 1 in open cells, ``sqrt(t)`` in closed ones with ``mask_leakage``, 0 outside the
  K×K area) to ``u``, has the field ``U = (H/(iλzd))·∬ A(m)·exp(iπ|m - m*|²/w²) d²m``:
  the Fresnel phase ``π/λ·(|m - s|²/z + |u - m|²/d)`` is, up to a constant, that quadratic
  around the crossing point ``m* = (z·u + d·s)/H`` with ``w² = λ·z·d/H`` (``|U| = 1``
  behind an unbounded open mask);
- the mask is a union of K² cells; Fresnel's kernel is rotation-invariant, so in the
  pattern's frame ``p = Rot(-θ)(m - (dx, dy))`` (``mask_misalignment``) every cell is an
  axis-aligned rectangle and its integral is **exactly** a product of two 1-D Fresnel
  integrals (``scipy.special.fresnel``) around ``p* = Rot(-θ)(m* - (dx, dy))``; ``U`` is
  their sum over all cells (no window, no tabulation);
- the irradiance is ``|U|²`` times the baseline's radiometric factor ``cos^(4+p)θ/H²``
  (its λ → 0 limit is then the §4 baseline); with ``refraction`` the factor and the
  crossing point are those of the refracted ray (Snell's law, as in
  :mod:`~thintact_sdk.simulation.reference`) and the Fresnel width is that of the
  paraxial phase with a scene gap of optical thickness ``z/n``:
  ``w² = λ·(z/n)·d/(z/n + d)``. The contract does not spell out this composition; this is
  the definition the simulator documents, checked here for its numerics.

Only the pixel integration is approximate. Three integrators, each converged by refining it:

- :func:`subsampled_reference_kernel`: the definition read literally, ``n²`` sub-samples per
  sensor pixel and per scene pixel. Simple but slow to converge: the fringes of far edges
  (period ``w²/x``, under 1 µm) alias until ``n`` resolves them in both pixels (on the test
  device n = 48 is still 6e-4 off);
- :func:`crossing_grid_reference_kernel` (straight rays): the exact change of variables
  ``(u, s) → (m, δ)``, a fine midpoint grid in the mask plane and Gauss-Legendre in ``δ``;
  converges as ``step²`` (5e-6 between 0.1 and 0.05 µm);
- :func:`ray_offset_reference_kernel` (straight or refracted rays): ``δ`` outermost,
  summed-area table of ``|U|²`` inside.

The three agree where all converge (tests/simulator/test_sim_diffraction_bruteforce.py);
``tools/measure_diffraction_reference.py`` prints the simulator's error table.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import fresnel

from thintact_sdk.formats.profiles import Profile
from thintact_sdk.simulation.effects import mask_misalignment, refraction, resolve_physics

SNELL_TABLE_POINTS = 200_001
"""Lateral offsets at which Snell's law is solved (uniform in ρ, linear interpolation)."""


def pixel_nodes(n: int, pitch_mm: float, rule: str = "gauss") -> tuple[np.ndarray, np.ndarray]:
    """``(offsets (n,) mm, weights (n,))`` of one pixel axis; the weights sum to 1.

    ``rule`` is ``"gauss"`` (Gauss-Legendre) or ``"midpoint"``.
    """
    if rule == "gauss":
        x, wt = np.polynomial.legendre.leggauss(n)
        return x * pitch_mm / 2, wt / 2
    if rule == "midpoint":
        return ((np.arange(n) + 0.5) / n - 0.5) * pitch_mm, np.full(n, 1.0 / n)
    raise ValueError(f"unknown quadrature rule {rule!r}")


def cell_amplitudes(profile: Profile, transmittance: float) -> np.ndarray:
    """``(K, K)`` amplitude transmittance of the cells (row i along y, column j along x)."""
    phi = np.asarray(profile.mask.phi, float)
    phi_r = np.asarray(profile.mask.rows_vector, float)
    open_ = phi_r[:, None] * phi[None, :] > 0
    return np.where(open_, 1.0, math.sqrt(transmittance))


def _contract_setup(profile: Profile) -> tuple[float, float, float, float, tuple[float, float, float], np.ndarray]:
    """What the contract's §4/§5 definitions take from ``profile`` and its ``physics``: z and d
    (mm, ``geometry`` or nominal), the scene-side index, the angular-response exponent, the mask's
    (angle °, dx µm, dy µm) and the cells' amplitudes (``mask_leakage`` included)."""
    ph = resolve_physics(profile.physics)
    g = ph.get("geometry", {})
    z = g.get("scene_to_mask_mm") or profile.geometry.scene_to_mask_mm
    d = g.get("mask_to_sensor_mm") or profile.geometry.mask_to_sensor_mm
    mis = ph.get("mask_misalignment", {})
    return (float(z), float(d), float(ph.get("refraction", {}).get("n_scene_side", 1.0)),
            float(ph.get("pixel_angular_response", {}).get("exponent", 0.0)),
            (float(mis.get("angle_deg", 0.0)), float(mis.get("dx_um", 0.0)), float(mis.get("dy_um", 0.0))),
            cell_amplitudes(profile, ph.get("mask_leakage", {}).get("transmittance", 0.0)))


def _pixel_grids(profile: Profile, sensor_pixels: np.ndarray | None, scene_pixels: np.ndarray | None,
                 ) -> tuple[tuple[int, int, float], tuple[int, int, float], np.ndarray, np.ndarray]:
    """``(rows, cols, pitch mm)`` of the sensor and of the scene, and the flat indices of the
    sensor and scene pixels asked for (every pixel when ``None``)."""
    rows, cols, nr, nc = profile.sensor.rows, profile.sensor.cols, profile.scene.rows, profile.scene.cols
    sens = np.arange(rows * cols) if sensor_pixels is None else np.asarray(sensor_pixels)
    scen = np.arange(nr * nc) if scene_pixels is None else np.asarray(scene_pixels)
    return ((rows, cols, profile.sensor.pixel_pitch_um * 1e-3), (nr, nc, profile.scene.pixel_pitch_um * 1e-3),
            sens, scen)


def _edge_differences(p_mm: np.ndarray, edges_mm: np.ndarray, w_mm: float) -> np.ndarray:
    """``E(t_{j+1}) - E(t_j)`` with ``t = sqrt(2)(e - p)/w``: ``p.shape + (K,)`` complex."""
    t = math.sqrt(2.0) * (edges_mm - p_mm[..., None]) / w_mm
    s, c = fresnel(t)
    e = c + 1j * s
    return e[..., 1:] - e[..., :-1]


def fresnel_field(px_mm: np.ndarray, py_mm: np.ndarray, edges_mm: np.ndarray,
                  amplitudes: np.ndarray, w_mm: float) -> np.ndarray:
    """Field behind the mask at pattern-frame crossing points ``(px, py)`` (any shape):
    ``(1/2i)·Σ_ij A_ij ΔE_y,i ΔE_x,j`` (1 behind an unbounded open mask)."""
    ex = _edge_differences(px_mm, edges_mm, w_mm)
    ey = _edge_differences(py_mm, edges_mm, w_mm)
    return np.einsum("...i,ij,...j->...", ey, amplitudes, ex, optimize=True) / 2j


def subsampled_reference_kernel(profile: Profile, wavelength_nm: float, n_sensor: int = 8,
                             n_scene: int = 8, sensor_pixels: np.ndarray | None = None,
                             scene_pixels: np.ndarray | None = None,
                             rule: str = "gauss") -> np.ndarray:
    """The imaging operator with diffraction at one wavelength, by brute force.

    Parameters
    ----------
    profile
        The device; its ``physics`` may hold ``mask_misalignment``, ``mask_leakage``,
        ``pixel_angular_response``, ``geometry`` and ``refraction`` (``diffraction``'s
        own wavelengths are ignored: ``wavelength_nm`` is used).
    wavelength_nm
        Wavelength (nm).
    n_sensor, n_scene
        Sub-samples per axis in every sensor pixel and every scene pixel.
    sensor_pixels, scene_pixels
        Flat (row-major) indices of the sensor and scene pixels to compute (default all).
    rule
        ``"gauss"`` (Gauss-Legendre) or ``"midpoint"`` sub-samples.

    Returns
    -------
    numpy.ndarray
        ``(sensor pixels, scene pixels)``: irradiance averaged over the sensor pixel and
        integrated over the scene pixel, per unit scene radiance (the simulator's units).
    """
    z, d, n_idx, p_exp, (angle, dx_um, dy_um), amps = _contract_setup(profile)
    k = profile.mask.K
    delta = profile.mask.feature_um * 1e-3
    edges = (np.arange(k + 1) - k / 2) * delta
    z_opt = z / n_idx
    w = math.sqrt(wavelength_nm * 1e-6 * z_opt * d / (z_opt + d))

    (rows, cols, pitch), (nr, nc, spitch), sens, scen = _pixel_grids(profile, sensor_pixels, scene_pixels)
    off_u, wt_u = pixel_nodes(n_sensor, pitch, rule)
    off_s, wt_s = pixel_nodes(n_scene, spitch, rule)
    # weights of the (uy, ux, sy, sx) sub-sample grid; the scene pixel is integrated
    weight = (wt_u[:, None, None, None] * wt_u[None, :, None, None]
              * wt_s[None, None, :, None] * wt_s[None, None, None, :]) * spitch**2
    uy_o, ux_o = off_u[:, None, None, None], off_u[None, :, None, None]
    sy_o, sx_o = off_s[None, None, :, None], off_s[None, None, None, :]

    if n_idx != 1.0:
        corner = math.hypot(rows * pitch + nr * spitch, cols * pitch + nc * spitch) / 2
        rho_t = np.linspace(0.0, corner * 1.001 + 1e-9, SNELL_TABLE_POINTS)
        kappa_t, factor_t = refraction.crossing_fraction_and_factor(rho_t, z, d, n_idx, p_exp)

    out = np.empty((sens.size, scen.size))
    for a, i_u in enumerate(sens):
        r, c = divmod(int(i_u), cols)
        uy = (r - (rows - 1) / 2) * pitch + uy_o
        ux = (c - (cols - 1) / 2) * pitch + ux_o
        for b, j_s in enumerate(scen):
            n_, m_ = divmod(int(j_s), nc)
            sy = (n_ - (nr - 1) / 2) * spitch + sy_o
            sx = (m_ - (nc - 1) / 2) * spitch + sx_o
            ddx, ddy = sx - ux, sy - uy
            rho = np.sqrt(ddx**2 + ddy**2)
            if n_idx == 1.0:
                h = z + d
                kappa = d / h
                factor = h ** (2 + p_exp) / (h**2 + rho**2) ** ((4 + p_exp) / 2)
            else:
                kappa = np.interp(rho, rho_t, kappa_t)
                factor = np.interp(rho, rho_t, factor_t)
            mx, my = ux + ddx * kappa, uy + ddy * kappa
            px, py = mask_misalignment.pattern_coordinates(mx, my, angle, dx_um, dy_um)
            px, py = np.broadcast_arrays(px, py)
            if angle == 0.0 and n_idx == 1.0:
                # p_x depends on (ux, sx) only, p_y on (uy, sy): fields per axis, then the sum
                ex = _edge_differences(px[0, :, 0, :], edges, w)  # (n_u, n_s, K)
                ey = _edge_differences(py[:, 0, :, 0], edges, w)
                field = np.einsum("aci,ij,bdj->abcd", ey, amps, ex, optimize=True) / 2j
            else:
                field = fresnel_field(px, py, edges, amps, w)
            out[a, b] = float(np.sum(weight * factor * np.abs(field) ** 2))
    return out


def crossing_grid_reference_kernel(profile: Profile, wavelength_nm: float, step_um: float = 0.05,
                                   n_delta: int = 3, sensor_pixels: np.ndarray | None = None,
                                   scene_pixels: np.ndarray | None = None) -> np.ndarray:
    """:func:`subsampled_reference_kernel` by an exact change of variables (straight rays).

    With ``m = α·u + β·s`` (``α = z/H``, ``β = d/H``) and ``δ = s - u`` the map
    ``(u, s) → (m, δ)`` has Jacobian 1 per axis, so the pixel pair's 4-D integral is
    ``∬ |U(m)|²·W(m) d²m`` with ``W(m) = ∬ cos^(4+p)θ/H² d²δ`` over the rectangle of ``δ``
    that keeps ``u = m - β·δ`` in the sensor pixel and ``s = m + α·δ`` in the scene pixel.
    ``W`` is smooth across that rectangle (``|δ| ≪ H``) and is integrated by an
    ``n_delta × n_delta`` Gauss-Legendre rule on it (exact to ~(|δ|/H)^(2·n_delta)); the
    ``m`` integral is a midpoint sum on a square grid of ``step_um`` aligned with the mask
    pattern (the field there is ``|U|²`` of :func:`fresnel_field`, exact at every node),
    which resolves every fringe the mask can make on the device and converges as
    ``step²`` (the only discretisation left; the grid's error is shown by refining it).

    Parameters
    ----------
    profile, wavelength_nm, sensor_pixels, scene_pixels
        As :func:`subsampled_reference_kernel`; ``refraction`` is not supported here.
    step_um
        Grid step in the mask plane (µm).
    n_delta
        Gauss-Legendre nodes per axis of the ``δ`` rectangle.

    Returns
    -------
    numpy.ndarray
        ``(sensor pixels, scene pixels)`` in the simulator's units.
    """
    z, d, n_idx, p_exp, (angle_deg, dx_um, dy_um), amps = _contract_setup(profile)
    if n_idx != 1.0:
        raise ValueError("crossing_grid_reference_kernel: straight rays only (no refraction)")
    a = math.radians(angle_deg)
    ca, sa = math.cos(a), math.sin(a)
    sx_mm, sy_mm = dx_um * 1e-3, dy_um * 1e-3
    k = profile.mask.K
    edges = (np.arange(k + 1) - k / 2) * profile.mask.feature_um * 1e-3
    h = z + d
    alpha, beta = z / h, d / h
    w = math.sqrt(wavelength_nm * 1e-6 * z * d / h)
    step = step_um * 1e-3
    xg, wg = np.polynomial.legendre.leggauss(n_delta)

    (rows, cols, pitch), (nr, nc, spitch), sens, scen = _pixel_grids(profile, sensor_pixels, scene_pixels)

    def box(i: int, n: int, pit: float) -> tuple[float, float]:
        c = (i - (n - 1) / 2) * pit
        return c - pit / 2, c + pit / 2

    def delta_rule(m: np.ndarray, u: tuple[float, float], s: tuple[float, float]
                   ) -> tuple[np.ndarray, np.ndarray]:
        """Gauss nodes ``(…, n_delta)`` and weights of the ``δ`` interval at ``m``."""
        lo = np.maximum((m - u[1]) / beta, (s[0] - m) / alpha)
        hi = np.minimum((m - u[0]) / beta, (s[1] - m) / alpha)
        half = np.clip(hi - lo, 0.0, None) / 2
        return (lo + hi)[..., None] / 2 + half[..., None] * xg, half[..., None] * wg

    out = np.empty((sens.size, scen.size))
    for ia, i_u in enumerate(sens):
        r, c = divmod(int(i_u), cols)
        uy, ux = box(r, rows, pitch), box(c, cols, pitch)
        for ib, j_s in enumerate(scen):
            n_, m_ = divmod(int(j_s), nc)
            sy, sx = box(n_, nr, spitch), box(m_, nc, spitch)
            # the pair's footprint in the mask plane, its corners in the pattern frame
            fx = np.array([alpha * ux[0] + beta * sx[0], alpha * ux[1] + beta * sx[1]])
            fy = np.array([alpha * uy[0] + beta * sy[0], alpha * uy[1] + beta * sy[1]])
            cx, cy = np.meshgrid(fx - sx_mm, fy - sy_mm)
            px_c, py_c = ca * cx + sa * cy, -sa * cx + ca * cy
            kx = np.arange(math.floor(px_c.min() / step), math.ceil(px_c.max() / step))
            ky = np.arange(math.floor(py_c.min() / step), math.ceil(py_c.max() / step))
            px, py = (kx + 0.5) * step, (ky + 0.5) * step
            ex = _edge_differences(px, edges, w)  # (Nx, K)
            ey = _edge_differences(py, edges, w)  # (Ny, K)
            inten = np.abs(ey @ amps @ ex.T) ** 2 / 4  # (Ny, Nx)
            # grid nodes back in the sensor frame: m = Rot(θ)·p + shift
            mx = ca * px[None, :] - sa * py[:, None] + sx_mm
            my = sa * px[None, :] + ca * py[:, None] + sy_mm
            dxn, dxw = delta_rule(mx, ux, sx)
            dyn, dyw = delta_rule(my, uy, sy)
            weight = np.zeros_like(mx)
            for ga in range(n_delta):
                for gb in range(n_delta):
                    rho2 = dxn[..., ga] ** 2 + dyn[..., gb] ** 2
                    weight += dxw[..., ga] * dyw[..., gb] * h ** (2 + p_exp) \
                        / (h**2 + rho2) ** ((4 + p_exp) / 2)
            out[ia, ib] = float(np.sum(inten * weight)) * step**2 / pitch**2
    return out


def ray_offset_reference_kernel(profile: Profile, wavelength_nm: float, step_um: float = 0.1,
                                n_delta: int = 12, sensor_pixels: np.ndarray | None = None,
                                scene_pixels: np.ndarray | None = None) -> np.ndarray:
    """:func:`subsampled_reference_kernel` with the ray offset ``δ = s - u`` outermost
    (straight or refracted rays).

    The crossing point is ``m = u + g(δ)`` with ``g(δ) = κ(|δ|)·δ`` (``κ = d/H`` in air, the
    Snell crossing fraction with ``refraction``); ``(u, s) → (m, δ)`` has Jacobian 1, and
    for a fixed ``δ`` the pixel pair covers the rectangle ``m ∈ g(δ) + [U ∩ (S - δ)]``
    (``U``, ``S`` the sensor and scene pixels' squares). So the pair's integral is
    ``∬ F(|δ|)·I(δ) d²δ`` with ``F`` the radiometric factor and ``I(δ)`` the integral of
    ``|U(m)|²`` over that rectangle. Per axis the rectangle's ends are linear in ``δ``
    between the breakpoints ``s0 - u1, s0 - u0, s1 - u1, s1 - u0``: ``δ`` is integrated by
    ``n_delta`` Gauss-Legendre nodes on each of the three pieces per axis, and ``I(δ)`` is
    read from a summed-area table of ``|U|²`` at the midpoints of a ``step_um`` grid in the
    sensor frame (bilinear in the cumulative table: exact for the piecewise-constant field,
    error ``O(step²)``).

    Parameters
    ----------
    profile, wavelength_nm, sensor_pixels, scene_pixels
        As :func:`subsampled_reference_kernel` (``refraction`` allowed).
    step_um
        Grid step of the field table (µm).
    n_delta
        Gauss-Legendre nodes per piece and axis of ``δ``.

    Returns
    -------
    numpy.ndarray
        ``(sensor pixels, scene pixels)`` in the simulator's units.
    """
    z, d, n_idx, p_exp, (angle, dx_um, dy_um), amps = _contract_setup(profile)
    k = profile.mask.K
    edges = (np.arange(k + 1) - k / 2) * profile.mask.feature_um * 1e-3
    z_opt = z / n_idx
    w = math.sqrt(wavelength_nm * 1e-6 * z_opt * d / (z_opt + d))
    step = step_um * 1e-3
    xg, wg = np.polynomial.legendre.leggauss(n_delta)

    (rows, cols, pitch), (nr, nc, spitch), sens, scen = _pixel_grids(profile, sensor_pixels, scene_pixels)
    corner = math.hypot(rows * pitch + nr * spitch, cols * pitch + nc * spitch) / 2
    rho_t = np.linspace(0.0, corner * 1.001 + 1e-9, SNELL_TABLE_POINTS)
    if n_idx == 1.0:
        h = z + d
        kappa_t = np.full_like(rho_t, d / h)
        factor_t = h ** (2 + p_exp) / (h**2 + rho_t**2) ** ((4 + p_exp) / 2)
    else:
        kappa_t, factor_t = refraction.crossing_fraction_and_factor(rho_t, z, d, n_idx, p_exp)

    def box(i: int, n: int, pit: float) -> tuple[float, float]:
        c = (i - (n - 1) / 2) * pit
        return c - pit / 2, c + pit / 2

    def delta_nodes(u: tuple[float, float], s: tuple[float, float]
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Gauss nodes and weights of δ on the three pieces, and the ``U ∩ (S - δ)`` ends."""
        br = np.sort([s[0] - u[1], s[0] - u[0], s[1] - u[1], s[1] - u[0]])
        lo, hi = br[:-1], br[1:]
        nodes = ((lo + hi)[:, None] / 2 + (hi - lo)[:, None] / 2 * xg).ravel()
        weights = ((hi - lo)[:, None] / 2 * wg).ravel()
        return (nodes, weights, np.maximum(u[0], s[0] - nodes), np.minimum(u[1], s[1] - nodes))

    def cumulative(x: np.ndarray, x0: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Cell index and fraction of ``x`` on a grid of edges ``x0 + i·step``."""
        pos = np.clip((x - x0) / step, 0.0, n - 1e-9)
        i = np.floor(pos).astype(np.int64)
        return i, pos - i

    out = np.empty((sens.size, scen.size))
    for ia, i_u in enumerate(sens):
        r, c = divmod(int(i_u), cols)
        uy, ux = box(r, rows, pitch), box(c, cols, pitch)
        for ib, j_s in enumerate(scen):
            n_, m_ = divmod(int(j_s), nc)
            sy, sx = box(n_, nr, spitch), box(m_, nc, spitch)
            nx, wx, ax0, ax1 = delta_nodes(ux, sx)
            ny, wy, ay0, ay1 = delta_nodes(uy, sy)
            dxx, dyy = nx[None, :], ny[:, None]
            rho = np.sqrt(dxx**2 + dyy**2)
            kappa = np.interp(rho, rho_t, kappa_t)
            factor = np.interp(rho, rho_t, factor_t)
            # rectangle of m for every δ node: (Ny, Nx) arrays of its four ends
            x0, x1 = ax0[None, :] + kappa * dxx, ax1[None, :] + kappa * dxx
            y0, y1 = ay0[:, None] + kappa * dyy, ay1[:, None] + kappa * dyy
            valid = (x1 > x0) & (y1 > y0)
            gx0 = math.floor(float(x0[valid].min()) / step) * step
            gy0 = math.floor(float(y0[valid].min()) / step) * step
            ncx = int(math.ceil((float(x1[valid].max()) - gx0) / step)) + 1
            ncy = int(math.ceil((float(y1[valid].max()) - gy0) / step)) + 1
            mx = gx0 + (np.arange(ncx) + 0.5) * step
            my = gy0 + (np.arange(ncy) + 0.5) * step
            if angle == 0.0:
                ex = _edge_differences(mx - dx_um * 1e-3, edges, w)
                ey = _edge_differences(my - dy_um * 1e-3, edges, w)
                inten = np.abs(ey @ amps @ ex.T) ** 2 / 4
            else:
                px, py = mask_misalignment.pattern_coordinates(
                    mx[None, :], my[:, None], angle, dx_um, dy_um)
                inten = np.abs(fresnel_field(px, py, edges, amps, w)) ** 2
            cum = np.zeros((ncy + 1, ncx + 1))
            cum[1:, 1:] = np.cumsum(np.cumsum(inten, axis=0), axis=1) * step**2

            def table(xq: np.ndarray, yq: np.ndarray, cum: np.ndarray = cum,
                      ncx: int = ncx, ncy: int = ncy, gx0: float = gx0,
                      gy0: float = gy0) -> np.ndarray:
                ix, fx = cumulative(xq, gx0, ncx)
                iy, fy = cumulative(yq, gy0, ncy)
                return ((1 - fy) * ((1 - fx) * cum[iy, ix] + fx * cum[iy, ix + 1])
                        + fy * ((1 - fx) * cum[iy + 1, ix] + fx * cum[iy + 1, ix + 1]))

            rect = table(x1, y1) - table(x0, y1) - table(x1, y0) + table(x0, y0)
            rect = np.where(valid, rect, 0.0)
            out[ia, ib] = float(np.sum(wy[:, None] * wx[None, :] * factor * rect)) / pitch**2
    return out
