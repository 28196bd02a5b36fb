"""Partial slip from the marker displacement field (incipient-slip detection).

Under a tangential load below sliding, the centre of the contact sticks to the object and
moves with it rigidly while an annulus at the rim slips and lags behind (Cattaneo–Mindlin;
the slip region grows inwards until gross sliding). As in the vision-based incipient-slip
literature (Yuan et al., ICRA 2015, GelSight shear and slip; Dong et al., IROS 2017), the
displacement field is compared with the rigid motion of the stuck centre:

1. the loaded core is the region deeper than half the peak depth
   (:func:`thintact_sdk.tactile.force.loaded_core`);
2. the stick motion δ is the median displacement of the markers at the deepest part of
   the core (depth ≥ 80 % of the peak; else the marker nearest the peak);
3. the marker displacements are interpolated linearly over the core's pixels, and a pixel
   slips where its displacement departs from δ by more than ``tolerance · |δ|``;
4. ``slip_ratio`` = slipping area / core area: 0 = stuck, → 1 = gross sliding.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import griddata

from thintact_sdk.tactile.force import loaded_core, markers_in

MIN_SHEAR_MM = 0.05
STICK_TOLERANCE = 0.2


def estimate_slip_ratio(
    depth_mm: np.ndarray,
    mm_per_px: float,
    threshold_mm: float,
    reference_mm: np.ndarray,
    displacements_mm: np.ndarray,
    tolerance: float = STICK_TOLERANCE,
    min_shear_mm: float = MIN_SHEAR_MM,
) -> float | None:
    """Fraction of the loaded contact that slips, in [0, 1].

    Parameters
    ----------
    depth_mm
        ``N × M`` indentation (mm).
    mm_per_px, threshold_mm
        Pixel size and contact threshold (mm).
    reference_mm, displacements_mm
        ``K × 2`` marker reference centres and displacements (mm, NaN where lost).
    tolerance
        Relative departure from the stick motion that counts as slip.
    min_shear_mm
        Below this stick motion there is no tangential load: the ratio is 0.

    Returns
    -------
    float or None
        None when it cannot be told: no contact, or fewer than 3 tracked markers in and
        around the core.
    """
    core = loaded_core(depth_mm, mm_per_px, threshold_mm)
    if core is None:
        return None
    ref = np.asarray(reference_mm, np.float64).reshape(-1, 2)
    disp = np.asarray(displacements_mm, np.float64).reshape(-1, 2)
    tracked = np.isfinite(disp).all(axis=1)
    inside = markers_in(core.mask, ref, mm_per_px) & tracked
    if inside.sum() < 3:
        return None
    depth = np.asarray(depth_mm, np.float64)
    deep = markers_in(depth >= 0.8 * depth.max(), ref, mm_per_px) & tracked
    if deep.any():
        stick = np.median(disp[deep], axis=0)
    else:
        rows, cols = depth.shape
        pr, pc = np.unravel_index(int(np.argmax(depth)), depth.shape)
        peak = np.array([(pc - (cols - 1) / 2) * mm_per_px, (pr - (rows - 1) / 2) * mm_per_px])
        cand = np.flatnonzero(inside)
        stick = disp[cand[np.argmin(np.hypot(*(ref[cand] - peak).T))]]
    size = float(np.hypot(*stick))
    if size < min_shear_mm:
        return 0.0
    rr, cc = np.nonzero(core.mask)
    rows, cols = depth.shape
    pix = np.stack([(cc - (cols - 1) / 2) * mm_per_px, (rr - (rows - 1) / 2) * mm_per_px], 1)
    field = griddata(ref[tracked], disp[tracked], pix, method="linear")
    holes = ~np.isfinite(field).all(axis=1)
    if holes.any():
        field[holes] = griddata(ref[tracked], disp[tracked], pix[holes], method="nearest")
    departs = np.hypot(*(field - stick).T) > tolerance * size
    return float(np.clip(departs.mean(), 0.0, 1.0))
