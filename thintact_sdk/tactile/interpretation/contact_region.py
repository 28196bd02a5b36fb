"""The contact region of a depth map: where the membrane wraps the object, not its skirt.

A real gel sinks in around an indenter: outside the contact the membrane is still pushed
down (a skirt that decays over about the layer's thickness), so the region deeper than the
contact threshold is wider than the contact (measured on two real GelSight ball-press packs
in docs/tactile.md, "Depth on real gels"), while the reconstructed cap itself has the ball's
shape.

Inside a contact with a convex object the membrane takes the object's shape and curves
down away from the deepest point (negative Laplacian of depth); in the skirt it curves back
up towards the undeformed level (positive Laplacian). The rim of the contact is where the
curvature changes sign. So the contact region is

1. the pixels deeper than the contact threshold where the depth is concave (Laplacian < 0,
   of a Gaussian one pixel of the grid the depth was reconstructed on wide: the finest
   detail it holds; a wider one moves the rim of a steep cap inwards),
2. of these, the connected parts that hold the deepest point of a region deeper than the
   contact threshold (a frame with nothing deeper than the threshold has no contact;
   concave speckle of noise and drift beside a contact holds no such point),
3. with their holes filled: the flat face of a punch has no curvature inside its
   concave rim; a rim cut by the frame's edge counts as closed where the depth at the edge
   is over the contact threshold,
4. grown by ``rim_mm`` into the pixels deeper than the contact threshold
   (:func:`grown`): the device's calibration says how far its own smoothing moves the sign
   change inside the rim.

A region deeper than the threshold whose deepest point is not concave (no curvature
resolved there) counts whole.

No parameter is fitted here: the smoothing scale is the reconstruction's own pixel and the
sign change needs no level. Smoothing moves the sign change inwards: a kink of the surface at
the rim (the membrane leaving a rigid object with a slope) becomes a ridge of positive
curvature about as wide as the smoothing, which outweighs the object's own curvature up to
about a smoothing width inside the rim. How far depends on the sensor's smoothing (elastomer,
optics, reconstruction) and the object, so it is the calibration's: ``calibrate-tactile``
measures it on the shape its ball model teaches the sensor, at the calibration presses
(``contact_rim_mm`` in the calibration's metadata,
:func:`~thintact_sdk.tactile.calibration.ball_press.contact_rim_offset`).

For a membrane under tension on an elastic foundation (a gel on glass) a negative Laplacian
means an outside pressure pushes it there, i.e. contact; where the object's face is flat the
pressure is held by the foundation alone, hence the filled holes.
"""

from __future__ import annotations

import cv2
import numpy as np

MIN_SMOOTH_PX = 1.0
"""Smallest Laplacian-of-Gaussian width in pixels: one pixel of the grid the depth is on (a
narrower Gaussian is not sampled by the grid)."""


def contact_region(depth_mm: np.ndarray, mm_per_px: float, threshold_mm: float,
                   smooth_mm: float = 0.0, rim_mm: float = 0.0) -> np.ndarray:
    """``N × M`` bool: the pixels in contact (module docstring).

    Parameters
    ----------
    depth_mm
        ``N × M`` depth in mm (positive into the elastomer).
    mm_per_px
        Pixel size in mm.
    threshold_mm
        Contact threshold: a region counts only where some pixel is deeper.
    smooth_mm
        Width (σ, mm) of the Gaussian whose Laplacian measures the curvature: the pixel of
        the grid the depth was reconstructed on (the interpreter's working grid); at least
        one pixel of ``depth_mm``.
    rim_mm
        Distance (mm, ≥ 0) the region is grown by, into pixels deeper than the threshold:
        how far the sensor's smoothing moves the curvature's sign change inside the rim (step
        4 of the module docstring; 0: not grown).
    """
    d = np.asarray(depth_mm, np.float64)
    seeds = d > threshold_mm
    if not seeds.any():
        return np.zeros(d.shape, bool)
    sigma = max(smooth_mm / mm_per_px, MIN_SMOOTH_PX)
    smooth = cv2.GaussianBlur(d, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
    lap = cv2.Laplacian(smooth, cv2.CV_64F, ksize=1, borderType=cv2.BORDER_REPLICATE)
    concave = (lap < 0) & seeds
    labels = _components(concave)
    seed_labels = _components(seeds)
    # the deepest pixel of each region over the threshold
    idx = np.flatnonzero(seeds)
    idx = idx[np.argsort(-d.ravel()[idx], kind="stable")]
    _, first = np.unique(seed_labels.ravel()[idx], return_index=True)
    peaks = idx[first]
    at_peak = labels.ravel()[peaks]
    keep = np.zeros(int(labels.max()) + 1, bool)
    keep[at_peak[at_peak > 0]] = True
    whole = np.zeros(int(seed_labels.max()) + 1, bool)
    # no curvature resolved at its deepest point: the region counts whole (every peak lies
    # in a region, so label 0, outside them all, is never set)
    whole[seed_labels.ravel()[peaks[at_peak == 0]]] = True
    return grown(_filled(keep[labels], seeds) | whole[seed_labels], d, mm_per_px, threshold_mm,
                 rim_mm)


def grown(region: np.ndarray, depth_mm: np.ndarray, mm_per_px: float, threshold_mm: float,
          rim_mm: float) -> np.ndarray:
    """``region`` (``N × M`` bool) and the pixels deeper than ``threshold_mm`` whose centres
    lie within ``rim_mm`` of its boundary, which is half a pixel beyond its outermost pixels'
    centres (Euclidean distance between pixel centres up to ``rim_mm / mm_per_px + 0.5``
    pixels). ``region`` itself when ``rim_mm`` ≤ 0 or it is empty."""
    if rim_mm <= 0 or not region.any():
        return region
    outside = (~region).view(np.uint8)
    dist = cv2.distanceTransform(outside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return region | ((np.asarray(depth_mm) > threshold_mm) & (dist <= rim_mm / mm_per_px + 0.5))


def _components(mask: np.ndarray) -> np.ndarray:
    """4-connected component labels of ``mask`` (0 outside it)."""
    _, labels = cv2.connectedComponents(mask.view(np.uint8), connectivity=4)
    return labels


def _filled(part: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """``part`` with its holes filled, the frame's edge closing it where ``seeds``.

    Only the kept parts' own holes: a ring of concave pixels elsewhere (a blurred frame
    edge) is not in ``part`` and cannot enclose a skirt."""
    n, m = part.shape
    walls = np.zeros((n + 4, m + 4), np.uint8)  # an empty outer ring the flood starts from
    walls[2:-2, 2:-2] = part
    walls[1, 2:-2] |= seeds[0]
    walls[-2, 2:-2] |= seeds[-1]
    walls[2:-2, 1] |= seeds[:, 0]
    walls[2:-2, -2] |= seeds[:, -1]
    cv2.floodFill(walls, None, (0, 0), 2, flags=4)
    return walls[2:-2, 2:-2] != 2
