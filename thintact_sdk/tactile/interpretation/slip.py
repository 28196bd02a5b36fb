"""Partial slip from the marker displacement field (incipient-slip detection).

Under a tangential load below sliding, the centre of the contact sticks to the object and
moves with it rigidly while an annulus at the rim slips and lags behind (Cattaneo–Mindlin;
the slip region grows inwards until gross sliding). As in the vision-based incipient-slip
literature (Yuan et al., ICRA 2015, GelSight shear and slip; Dong et al., IROS 2017), the
displacement field is compared with the rigid motion of the stuck part:

1. the loaded core is the region deeper than half the peak depth
   (:func:`thintact_sdk.tactile.interpretation.force.loaded_core`);
2. the shear direction ŝ is that of the mean displacement of the core's markers; the stick
   motion δ is the ``stick_quantile`` (75 %) of their displacements along ŝ: the stuck part
   moves furthest, the slipping rim lags (a high quantile rather than the maximum, against
   tracking noise and the normal-load pull of the markers towards the contact);
3. the along-ŝ displacements of all tracked markers are interpolated over the core's
   pixels (inverse-distance weights of the 3 nearest markers), and a pixel slips where it lags δ by more than ``tolerance · δ``;
4. ``slip_ratio`` = slipping area / core area: 0 = stuck, → 1 = gross sliding.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from thintact_sdk.tactile.interpretation.force import loaded_core, markers_in

MIN_SHEAR_MM = 0.05
STICK_TOLERANCE = 0.2
STICK_QUANTILE = 0.75
SLIPPING_RATIO = 0.15
"""A frame whose slip ratio reaches this share is flagged as slipping (incipient slip): the
criterion of the force/slip evaluation (``thintact bench tactile``), below which stuck
presses' ratios stay (tracking noise and the normal-load drag of the markers)."""


def is_slipping(slip_ratio: float | None) -> bool:
    """True when ``slip_ratio`` (None: unknown) is at least :data:`SLIPPING_RATIO`."""
    return slip_ratio is not None and float(slip_ratio) >= SLIPPING_RATIO


def interpolate_markers(
    positions_mm: np.ndarray, values: np.ndarray, points_mm: np.ndarray, neighbours: int = 3
) -> np.ndarray:
    """Inverse-square-distance weighted mean of the ``neighbours`` nearest markers' values.

    Parameters
    ----------
    positions_mm
        ``K × 2`` marker positions (mm).
    values
        ``K`` values at the markers.
    points_mm
        ``P × 2`` where to interpolate (mm).

    Returns
    -------
    numpy.ndarray
        ``P`` float64 values (a point on a marker takes its value).
    """
    k = min(neighbours, len(positions_mm))
    dist, idx = cKDTree(positions_mm).query(points_mm, k=k)
    dist, idx = np.asarray(dist).reshape(len(points_mm), k), np.asarray(idx).reshape(len(points_mm), k)
    w = 1.0 / np.maximum(dist, 1e-6) ** 2
    return np.asarray((w * np.asarray(values)[idx]).sum(axis=1) / w.sum(axis=1), np.float64)


def estimate_slip_ratio(
    depth_mm: np.ndarray,
    mm_per_px: float,
    threshold_mm: float,
    reference_mm: np.ndarray,
    displacements_mm: np.ndarray,
    tolerance: float = STICK_TOLERANCE,
    stick_quantile: float = STICK_QUANTILE,
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
        Relative lag behind the stick motion that counts as slip.
    stick_quantile
        Quantile of the core markers' along-shear displacement taken as the stick motion.
    min_shear_mm
        Below this mean displacement of the core's markers there is no tangential load:
        the ratio is 0.

    Returns
    -------
    float or None
        None when it cannot be told: no contact, fewer than 2 tracked markers in the core,
        or fewer than 3 tracked markers in all.
    """
    core = loaded_core(depth_mm, mm_per_px, threshold_mm)
    if core is None:
        return None
    ref = np.asarray(reference_mm, np.float64).reshape(-1, 2)
    disp = np.asarray(displacements_mm, np.float64).reshape(-1, 2)
    tracked = np.isfinite(disp).all(axis=1)
    inside = markers_in(core.mask, ref, mm_per_px) & tracked
    if inside.sum() < 2 or tracked.sum() < 3:
        return None
    mean = disp[inside].mean(axis=0)
    size = float(np.hypot(*mean))
    if size < min_shear_mm:
        return 0.0
    along = disp[tracked] @ (mean / size)
    stick = float(np.quantile(disp[inside] @ (mean / size), stick_quantile))
    rows, cols = core.mask.shape
    rr, cc = np.nonzero(core.mask)
    pix = np.stack([(cc - (cols - 1) / 2) * mm_per_px, (rr - (rows - 1) / 2) * mm_per_px], 1)
    field = interpolate_markers(ref[tracked], along, pix)
    return float(np.clip(np.mean(field < (1.0 - tolerance) * stick), 0.0, 1.0))
