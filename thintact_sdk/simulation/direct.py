"""Direct (non-separable) simulator kernel for a rotated mask or a refracting scene gap.

The operator is built as a dense ``(R·S) × (N·M)`` float32 matrix, so this path is meant
for small devices (≈128×160 sensor, 50×64 scene: 65 M entries, a few seconds to build).

For every (sensor pixel, scene pixel) pair the mask is averaged over the distribution of
crossing points ``m = u + (s - u)·κ`` when ``u`` and ``s`` run over the two pixel squares.
For straight rays that distribution is the product of two boxes (widths ``(1-κ)·p`` and
``κ·p_scene``) per axis, so the average is the mask pattern blurred by those boxes
(computed exactly for the finely sampled pattern with cumulative sums) and read at the
pair's centre crossing point; with refraction the local widths of the paraxial ``κ0`` are
used and the centre crossing point follows Snell's law exactly. The smooth radiometric
factor (a function of ``|s - u|`` only, tabulated) is taken at the pair centre, so the
error is second order in (pair size / H).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from thintact_sdk.errors import ThinTactError
from thintact_sdk.simulation.effects import mask_misalignment, refraction
from thintact_sdk.simulation.params import KernelParams

STEP_FRACTION = 0.25
"""Fine-grid step as a fraction of the smallest of cell size and the two blur widths."""

MAX_ENTRIES = 400_000_000
"""Largest operator (R·S·N·M) the direct path builds."""


@dataclass
class DirectKernel:
    """A dense operator shared by all channels: ``Y[:, c] = G @ X[:, c]``."""

    G: np.ndarray  # noqa: N815 - (R·S, N·M) float32
    rows: int
    cols: int
    info: dict[str, float] = field(default_factory=dict)

    def apply(self, scenes: np.ndarray, dtype: str = "float32") -> np.ndarray:
        """``F × N × M × C`` scenes → ``F × R × S × C`` float64 signal (simulator units);
        the operator is stored in float32, so the arithmetic is float32 whatever ``dtype``."""
        f, n, m, c = scenes.shape
        x = np.asarray(scenes, np.float32).transpose(1, 2, 0, 3).reshape(n * m, f * c)
        y = (self.G @ x).astype(float)
        return y.reshape(self.rows, self.cols, f, c).transpose(2, 0, 1, 3)


def _box_blur(img: np.ndarray, width_cells: float, axis: int) -> np.ndarray:
    """Exact average of a piecewise-constant image over a centred box of ``width_cells``
    (in grid cells) along ``axis``, at every cell centre; outside the image counts as 0."""
    if width_cells <= 1e-9:
        return img
    a = np.moveaxis(img, axis, -1)
    n = a.shape[-1]
    cum = np.zeros(a.shape[:-1] + (n + 1,))
    np.cumsum(a, axis=-1, out=cum[..., 1:])
    centres = np.arange(n) + 0.5
    half = width_cells / 2

    def cum_at(t: np.ndarray) -> np.ndarray:
        t = np.clip(t, 0.0, float(n))
        i0 = np.clip(np.floor(t).astype(np.int64), 0, n - 1)
        w = t - i0
        return cum[..., i0] * (1 - w) + cum[..., i0 + 1] * w

    out = (cum_at(centres + half) - cum_at(centres - half)) / width_cells
    return np.moveaxis(out, -1, axis)


SUPERSAMPLE = 4
"""Sub-samples per fine-grid cell and axis when averaging the (rotated) pattern."""


def _mask_pattern(kp: KernelParams, xs: np.ndarray, ys: np.ndarray, step: float) -> np.ndarray:
    """Mean transmittance over each fine cell centred at ``ys × xs`` (mm), misalignment and
    leakage applied (``SUPERSAMPLE²`` sub-samples per cell)."""
    off = ((np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5) * step
    acc = np.zeros((ys.size, xs.size))
    for oy in off:
        for ox in off:
            acc += _point_pattern(kp, xs + ox, ys + oy)
    return acc / SUPERSAMPLE**2


def _point_pattern(kp: KernelParams, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    px, py = mask_misalignment.pattern_coordinates(xs[None, :], ys[:, None], kp.angle_deg,
                                                   kp.dx_um, kp.dy_um)
    k = len(kp.phi)
    delta = kp.feature_um * 1e-3
    jx = np.floor(px / delta + k / 2).astype(np.int64)
    jy = np.floor(py / delta + k / 2).astype(np.int64)
    inside = (jx >= 0) & (jx < k) & (jy >= 0) & (jy < k)
    phi = np.asarray(kp.phi, np.float32)
    phi_r = np.asarray(kp.phi_rows, np.float32)
    prod = phi_r[np.clip(jy, 0, k - 1)] * phi[np.clip(jx, 0, k - 1)]
    lk = np.float32(kp.leakage)
    return np.where(inside, np.where(prod > 0, np.float32(1.0), lk), np.float32(0.0))


def _radial_tables(kp: KernelParams, rho_max_mm: float, n: int = 20001
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(rho, kappa, factor)`` tables over ``[0, rho_max]`` (mm, 1, 1/mm²)."""
    rho = np.linspace(0.0, rho_max_mm * 1.001 + 1e-6, n)
    p = kp.q - 4.0
    if kp.n_scene_side == 1.0:
        h = kp.z_mm + kp.d_mm
        kappa = np.full_like(rho, kp.d_mm / h)
        factor = h ** (kp.q - 2) / (h**2 + rho**2) ** (kp.q / 2)
    else:
        kappa, factor = refraction.crossing_fraction_and_factor(
            rho, kp.z_mm, kp.d_mm, kp.n_scene_side, p)
    return rho, kappa, factor


def build_direct_kernel(kp: KernelParams) -> DirectKernel:
    """Build the dense operator for (possibly) non-separable physics."""
    rows, cols, nr, nc = kp.rows, kp.cols, kp.scene_rows, kp.scene_cols
    if rows * cols * nr * nc > MAX_ENTRIES:
        raise ThinTactError(
            f"the direct (non-separable) simulator path needs a {rows * cols}×{nr * nc} "
            f"operator, too large (limit {MAX_ENTRIES:.0e} entries); a rotated mask or "
            "refraction can only be simulated on a smaller device"
        )
    p, ps = kp.pitch_um * 1e-3, kp.scene_pitch_um * 1e-3
    uy = (np.arange(rows) - (rows - 1) / 2) * p
    ux = (np.arange(cols) - (cols - 1) / 2) * p
    sy = (np.arange(nr) - (nr - 1) / 2) * ps
    sx = (np.arange(nc) - (nc - 1) / 2) * ps
    rho_max = math.hypot(ux.max() + sx.max() + p, uy.max() + sy.max() + p)
    rho_t, kappa_t, factor_t = _radial_tables(kp, rho_max)
    kappa0 = float(kappa_t[0])
    k_lo, k_hi = float(kappa_t.min()), float(kappa_t.max())
    w_u, w_s = (1 - kappa0) * p, kappa0 * ps
    step = STEP_FRACTION * min(kp.feature_um * 1e-3, max(w_s, 1e-4), max(w_u, 1e-4))
    pad = w_u + w_s + 4 * step
    half_x = max((1 - k) * (ux.max() + p / 2) + k * (sx.max() + ps / 2) for k in (k_lo, k_hi)) + pad
    half_y = max((1 - k) * (uy.max() + p / 2) + k * (sy.max() + ps / 2) for k in (k_lo, k_hi)) + pad
    nx, ny = int(math.ceil(2 * half_x / step)), int(math.ceil(2 * half_y / step))
    x0, y0 = -nx * step / 2, -ny * step / 2
    xs = x0 + (np.arange(nx) + 0.5) * step
    ys = y0 + (np.arange(ny) + 0.5) * step
    pattern = _mask_pattern(kp, xs, ys, step)
    for axis in (0, 1):
        pattern = _box_blur(pattern, w_u / step, axis)
        pattern = _box_blur(pattern, w_s / step, axis)
    g4 = np.empty((rows, cols, nr, nc), np.float32)
    if kp.n_scene_side == 1.0:
        _fill_straight(g4, pattern, (x0, y0, step), (ux, uy, sx, sy), kp, ps)
    else:
        _fill_refracted(g4, pattern, (x0, y0, step), (ux, uy, sx, sy),
                        (rho_t, kappa_t, factor_t), ps)
    return DirectKernel(g4.reshape(rows * cols, nr * nc), rows, cols, {"grid_step_um": step * 1e3, "grid_cells": float(nx * ny)})


def _fill_straight(g: np.ndarray, pattern: np.ndarray, grid: tuple[float, float, float],
                   pos: tuple[np.ndarray, ...], kp: KernelParams, ps: float) -> None:
    """Straight rays: the crossing points of one scene pixel form a regular grid, so the
    bilinear look-up is a gather of two rows then two columns per point (float32)."""
    x0, y0, step = grid
    ux, uy, sx, sy = pos
    h = kp.z_mm + kp.d_mm
    kappa = kp.d_mm / h
    nyp, nxp = pattern.shape
    pat = pattern.astype(np.float32)
    cx = ((1 - kappa) * ux[:, None] + kappa * sx[None, :] - x0) / step - 0.5  # (S, M)
    ix = np.clip(np.floor(cx).astype(np.int64), 0, nxp - 2)
    fx = (cx - ix).astype(np.float32)
    gx = 1 - fx
    dx2 = ((sx[None, :] - ux[:, None]) ** 2 / h**2).astype(np.float32)  # (S, M)
    scale = np.float32(ps**2 / h**2)
    half_q = kp.q / 2
    for i in range(sy.size):
        cy = ((1 - kappa) * uy + kappa * sy[i] - y0) / step - 0.5
        iy = np.clip(np.floor(cy).astype(np.int64), 0, nyp - 2)
        fy = (cy - iy).astype(np.float32)[:, None]
        rows_i = pat[iy] * (1 - fy) + pat[iy + 1] * fy  # (R, nx)
        t = rows_i[:, ix] * gx + rows_i[:, ix + 1] * fx  # (R, S, M)
        base = 1 + ((sy[i] - uy) ** 2 / h**2).astype(np.float32)[:, None, None] + dx2[None]
        if half_q == 2.0:
            inv = 1 / base
            factor = inv * inv
        else:
            factor = base ** np.float32(-half_q)
        g[:, :, i, :] = t * factor * scale


def _fill_refracted(g: np.ndarray, pattern: np.ndarray, grid: tuple[float, float, float],
                    pos: tuple[np.ndarray, ...], tables: tuple[np.ndarray, ...],
                    ps: float) -> None:
    """Refracted rays: crossing points from the tabulated Snell solution (uniform table in ρ,
    linear interpolation), bilinear look-up in the blurred pattern (float32)."""
    x0, y0, step = grid
    ux, uy, sx, sy = pos
    rho_t, kappa_t, factor_t = tables
    d_rho = float(rho_t[1] - rho_t[0])
    n_t = rho_t.size
    kap = kappa_t.astype(np.float32)
    fac = (factor_t * ps**2).astype(np.float32)
    nyp, nxp = pattern.shape
    flat = pattern.astype(np.float32).ravel()
    dx = (sx[None, :] - ux[:, None]).astype(np.float32)  # (S, M)
    f32 = np.float32
    cx0 = ((ux[:, None] - x0) / step - 0.5).astype(np.float32)  # (S, 1)
    dx_cells = dx / f32(step)
    cy0 = ((uy - y0) / step - 0.5).astype(np.float32)[:, None, None]  # (R, 1, 1)
    inv_drho = f32(1.0 / d_rho)

    def lerp(table: np.ndarray, idx: np.ndarray, w: np.ndarray) -> np.ndarray:
        return table[idx] * (1 - w) + table[idx + 1] * w

    for i in range(sy.size):
        dy = (sy[i] - uy).astype(np.float32)[:, None, None]  # (R, 1, 1)
        tpos = np.sqrt(dy**2 + dx[None] ** 2) * inv_drho  # (R, S, M), ρ in table steps
        it = np.minimum(tpos.astype(np.int32), n_t - 2)
        wt = tpos - it
        kappa = lerp(kap, it, wt)
        factor = lerp(fac, it, wt)
        cy = cy0 + (dy / f32(step)) * kappa
        cx = cx0[None] + dx_cells[None] * kappa
        iy = np.clip(cy.astype(np.int32), 0, nyp - 2)
        ix = np.clip(cx.astype(np.int32), 0, nxp - 2)
        wy = cy - iy
        wx = cx - ix
        base = iy.astype(np.int64) * nxp + ix
        t = ((flat[base] * (1 - wx) + flat[base + 1] * wx) * (1 - wy)
             + (flat[base + nxp] * (1 - wx) + flat[base + nxp + 1] * wx) * wy)
        g[:, :, i, :] = t * factor
