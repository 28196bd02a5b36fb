"""Depth from slopes by Poisson integration, in O(NM log NM) with fast cosine/sine transforms.

Two boundary conditions:

* ``"free"`` (default): least-squares integration with a free (Neumann) boundary, the
  discrete normal equations diagonalised by the type-II DCT (Simchony, Chellappa & Shao
  1990). Nothing is assumed about the frame's edge, so a press touching it keeps its depth.
  The solution is defined up to a constant: the reference level (depth 0) is the plane
  fitted to the depth where the membrane is flat (slope magnitude below ``flat_slope``),
  which is where it is not pressed (a constant slope bias, which integrates to a tilt, is
  removed with it), or, when flat pixels are under 5 % of the frame, the frame's 5th
  percentile.
* ``"zero"``: the 5-point Poisson equation with ``d = 0`` just outside the frame, by the
  type-I DST (the membrane pinned at the frame's edge; presses touching the edge read flat).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Literal

import numpy as np
from scipy.fft import dctn, dstn, idctn, idstn

Boundary = Literal["free", "zero"]
FLAT_SLOPE = 0.05
"""Slope magnitude (mm per mm) under which a pixel counts as flat for the reference level."""
_MIN_FLAT_SHARE = 0.05
_ROUND_OFF_MM = 1e-9


@lru_cache(maxsize=8)
def _inverse_eigenvalues(rows: int, cols: int) -> np.ndarray:
    ky = 2.0 * np.cos(np.pi * np.arange(1, rows + 1) / (rows + 1)) - 2.0
    kx = 2.0 * np.cos(np.pi * np.arange(1, cols + 1) / (cols + 1)) - 2.0
    return (1.0 / (ky[:, None] + kx[None, :])).astype(np.float64)


@lru_cache(maxsize=8)
def _inverse_neumann_eigenvalues(rows: int, cols: int) -> np.ndarray:
    ky = 2.0 * np.cos(np.pi * np.arange(rows) / rows) - 2.0
    kx = 2.0 * np.cos(np.pi * np.arange(cols) / cols) - 2.0
    den = ky[:, None] + kx[None, :]
    den[0, 0] = 1.0
    inv = 1.0 / den
    inv[0, 0] = 0.0  # the constant is fixed afterwards by the reference level
    return inv


def _free(gx: np.ndarray, gy: np.ndarray, mm_per_px: float, flat_slope: float) -> np.ndarray:
    # slopes at the half-pixel links between neighbours; none across the frame's edge
    px = np.zeros_like(gx)
    py = np.zeros_like(gy)
    px[:, :-1] = 0.5 * (gx[:, :-1] + gx[:, 1:])
    py[:-1] = 0.5 * (gy[:-1] + gy[1:])
    div = px + py
    div[:, 1:] -= px[:, :-1]
    div[1:] -= py[:-1]
    spec = dctn(div * mm_per_px, type=2, norm="ortho", workers=1)
    depth = idctn(spec * _inverse_neumann_eigenvalues(*gx.shape), type=2, norm="ortho", workers=1)
    flat = np.hypot(gx, gy) < flat_slope
    if flat.mean() < _MIN_FLAT_SHARE:
        return depth - float(np.percentile(depth, 5))
    # a constant slope bias integrates to a plane: the level is the plane through the flat
    # pixels (least squares on a subsample), not a single number
    rr, cc = np.nonzero(flat)
    step = max(1, len(rr) // 4000)
    rr, cc = rr[::step], cc[::step]
    a = np.c_[np.ones(len(rr)), rr - gx.shape[0] / 2, cc - gx.shape[1] / 2]
    coef, *_ = np.linalg.lstsq(a, depth[rr, cc], rcond=None)
    r = np.arange(gx.shape[0])[:, None] - gx.shape[0] / 2
    c = np.arange(gx.shape[1])[None, :] - gx.shape[1] / 2
    depth -= coef[0] + coef[1] * r + coef[2] * c
    depth[np.abs(depth) < _ROUND_OFF_MM] = 0.0  # an unpressed membrane reads exactly 0
    return depth


def integrate_gradients(
    grad_x: np.ndarray, grad_y: np.ndarray, mm_per_px: float,
    boundary: Boundary = "free", flat_slope: float = FLAT_SLOPE,
) -> np.ndarray:
    """Depth map whose slopes best match ``(grad_x, grad_y)``.

    Parameters
    ----------
    grad_x, grad_y
        ``N × M`` slopes ∂d/∂x (along columns) and ∂d/∂y (along rows), mm per mm.
    mm_per_px
        Pixel size in mm.
    boundary
        ``"free"``: no assumption at the frame's edge, depth 0 where the membrane is flat;
        ``"zero"``: depth 0 just outside the frame (see the module docstring).
    flat_slope
        ``"free"`` only: slope magnitude below which a pixel sets the reference level.

    Returns
    -------
    numpy.ndarray
        ``N × M`` float32 depth in mm (not clipped: noise can go slightly negative).
    """
    gx = np.asarray(grad_x, np.float64)
    gy = np.asarray(grad_y, np.float64)
    if boundary == "free":
        return _free(gx, gy, mm_per_px, flat_slope).astype(np.float32)
    if boundary != "zero":
        raise ValueError(f"boundary must be 'free' or 'zero', not {boundary!r}")
    div = np.gradient(gx, axis=1) + np.gradient(gy, axis=0)  # per px
    rhs = div * mm_per_px  # 5-point Laplacian in px² units, depth in mm
    inv = _inverse_eigenvalues(*gx.shape)
    # one worker: a per-frame transform of ~100 × 128 gains nothing from threads it must
    # start and wait for, and a stream runs it beside the decode of the next frame
    depth = idstn(dstn(rhs, type=1) * inv, type=1)
    return depth.astype(np.float32)
