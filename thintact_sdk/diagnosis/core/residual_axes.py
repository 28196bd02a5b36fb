"""Where a residual sits, along any axis a diagnosis chooses: the excess-χ² map and its
hotspots, the mean signed residual, χ² per value binned along a quantity or inside a mask.

``z`` is a residual in noise units (zero at invalid values) whose last axis is the channel
and whose first is the frame (imaging ``F × R × S × C``, tactile ``P × H × W × 3``);
``valid`` marks the values that count. Maps are ``R × S`` (rows × columns of the image).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage


@dataclass
class Hotspot:
    """A rectangle of sensor pixels ``[row0, row1) × [col0, col1)`` holding ``share`` of the
    excess χ² (χ² minus its expectation under the noise model)."""

    row0: int
    row1: int
    col0: int
    col1: int
    share: float

    def to_json(self) -> dict[str, Any]:
        return {
            "row0": self.row0,
            "row1": self.row1,
            "col0": self.col0,
            "col1": self.col1,
            "share": round(float(self.share), 4),
        }


@dataclass
class Profile1D:
    """Mean z² (χ² per value) against a binned quantity; ``centres`` in the quantity's unit."""

    name: str
    unit: str
    centres: np.ndarray
    chi2: np.ndarray
    counts: np.ndarray


def excess_map(z: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``R × S`` map of Σ over frames and channels of (z² − 1) at valid pixels."""
    return np.sum(np.where(valid, z * z - 1.0, 0.0), axis=(0, 3))


def find_hotspots(
    excess: np.ndarray,
    counts: np.ndarray,
    smooth_px: float = 2.0,
    min_sigma: float = 5.0,
    rel: float = 0.3,
    max_spots: int = 6,
    min_share: float = 0.02,
) -> list[Hotspot]:
    """Rectangles where the excess χ² concentrates.

    The excess map is smoothed with a Gaussian of ``smooth_px`` pixels and expressed in
    units of its null standard deviation (z² − 1 has variance 2 per value); pixels above
    both ``min_sigma`` and ``rel`` × the peak form connected regions whose bounding boxes
    are the hotspots, each with its share of the total positive excess.

    Parameters
    ----------
    excess
        ``R × S`` Σ (z² − 1).
    counts
        ``R × S`` number of valid values summed at each pixel.
    """
    total = float(np.sum(excess))
    if total <= 0:
        return []
    kern_norm = 1.0 / (4.0 * np.pi * smooth_px**2)  # Σ k² of a unit-sum 2-D Gaussian
    sm = ndimage.gaussian_filter(excess, smooth_px, mode="nearest")
    null_sd = np.sqrt(2.0 * np.maximum(ndimage.gaussian_filter(counts, smooth_px), 1.0) * kern_norm)
    s = sm / null_sd
    peak = float(s.max())
    if peak < min_sigma:
        return []
    hot = s > max(min_sigma, rel * peak)
    lab, n = ndimage.label(hot)
    spots: list[Hotspot] = []
    for sl in ndimage.find_objects(lab)[:n]:
        if sl is None:
            continue
        r0, r1 = int(sl[0].start), int(sl[0].stop)
        c0, c1 = int(sl[1].start), int(sl[1].stop)
        share = float(np.sum(excess[r0:r1, c0:c1])) / total
        if share >= min_share:
            spots.append(Hotspot(r0, r1, c0, c1, share))
    spots.sort(key=lambda h: -h.share)
    return spots[:max_spots]


def binned_chi2(x: np.ndarray, y: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``y`` (z², χ² per value) in the bins ``edges`` of ``x`` (flat arrays of one
    length); values beyond the outer edges count in the outer bins. Returns ``(mean per bin,
    NaN where empty; count per bin)``."""
    idx = np.clip(np.digitize(x, edges) - 1, 0, len(edges) - 2)
    cnt = np.bincount(idx, minlength=len(edges) - 1).astype(np.float64)
    tot = np.bincount(idx, weights=y, minlength=len(edges) - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan), cnt


def mean_z_map(z: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``R × S`` mean signed z over frames and channels at valid values (0 where none)."""
    nval = valid.sum(axis=(0, 3)).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(nval > 0, np.sum(z, axis=(0, 3)) / np.maximum(nval, 1), 0.0)


def chi2_in(z2: np.ndarray, mask: np.ndarray) -> float:
    """χ² per value (mean of ``z2``) inside ``mask``; NaN when the mask is empty."""
    return float(z2[mask].mean()) if mask.any() else float("nan")
