"""Black markers on the white membrane: lattice, rendering, sub-pixel detection, tracking.

Paper §III-E: markers are detected in every frame, matched to the previous frame by
nearest neighbour, and the matches are cascaded back to the reference frame to give each
marker's displacement. Positions are (x, y) in mm on the scene grid (CONTRACTS §1).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import cKDTree

from thintact_sdk.tactile.interpretation.grid import TactileParams


def marker_lattice_mm(params: TactileParams, margin_mm: float | None = None) -> np.ndarray:
    """Reference marker centres: a square lattice of ``marker_pitch_mm`` centred on the axis.

    Parameters
    ----------
    params
        Grid size, pixel size and marker geometry.
    margin_mm
        Keep markers whose centre is at least this far inside the field (default: one
        marker diameter).

    Returns
    -------
    numpy.ndarray
        ``K × 2`` float64 (x, y) in mm, row-major (y then x).
    """
    if margin_mm is None:
        margin_mm = params.marker_diameter_mm
    half_w = (params.cols - 1) / 2 * params.mm_per_px - margin_mm
    half_h = (params.rows - 1) / 2 * params.mm_per_px - margin_mm
    p = params.marker_pitch_mm
    nx, ny = int(np.floor(half_w / p)), int(np.floor(half_h / p))
    xs = np.arange(-nx, nx + 1) * p
    ys = np.arange(-ny, ny + 1) * p
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    return np.stack([xx.ravel(), yy.ravel()], axis=1)


def marker_coverage(positions_mm: np.ndarray, params: TactileParams) -> np.ndarray:
    """Anti-aliased coverage (0..1) of discs of ``marker_diameter_mm`` at ``positions_mm``.

    Returns
    -------
    numpy.ndarray
        ``N × M`` float64; 1 inside a marker, 0 on the membrane, partial on edges.
    """
    cov = np.zeros((params.rows, params.cols))
    r_px = params.marker_diameter_mm / 2 / params.mm_per_px
    rc = params.mm_to_px(positions_mm)
    w = int(np.ceil(r_px + 2))
    for row, col in rc:
        if not (np.isfinite(row) and np.isfinite(col)):
            continue
        r0, r1 = max(0, int(row) - w), min(params.rows, int(row) + w + 2)
        c0, c1 = max(0, int(col) - w), min(params.cols, int(col) + w + 2)
        if r0 >= r1 or c0 >= c1:
            continue
        rr, cc = np.mgrid[r0:r1, c0:c1]
        dist = np.hypot(rr - row, cc - col)
        cov[r0:r1, c0:c1] = np.maximum(cov[r0:r1, c0:c1], np.clip(r_px - dist + 0.5, 0.0, 1.0))
    return cov


@dataclass
class MarkerDetection:
    """Markers found in one image.

    Attributes
    ----------
    positions_mm
        ``K' × 2`` float64 (x, y) centres in mm (sub-pixel, darkness-weighted).
    mask
        ``N × M`` bool, pixels covered by a marker (dilated), to be ignored by photometric
        stereo.
    darkness
        ``N × M`` float32, 1 − grey/local background (0 membrane, ≈ 1 marker core).
    """

    positions_mm: np.ndarray
    mask: np.ndarray
    darkness: np.ndarray


def detect_markers(
    image: np.ndarray, params: TactileParams, threshold: float = 0.3
) -> MarkerDetection:
    """Detect dark markers in a (reconstructed) membrane image.

    The local membrane brightness comes from a grey-level closing with a square a little
    larger than a marker, so smooth shading from contact does not look like a marker.

    Parameters
    ----------
    image
        ``N × M × 3`` (or ``N × M``) float image, display units.
    params
        Pixel size and marker diameter.
    threshold
        Relative darkness (0..1) that starts a marker blob.
    """
    d_px = params.marker_diameter_mm / params.mm_per_px
    # a light blur (a quarter marker) suppresses pixel noise of reconstructed images
    blurred = cv2.GaussianBlur(np.ascontiguousarray(image, np.float32), (0, 0), max(0.5, d_px / 4))
    img = np.asarray(blurred, np.float32)
    if img.ndim == 2:
        img = img[..., None]
    k = int(2 * np.ceil(d_px) + 1) | 1
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    darkness = np.ones(img.shape[:2], np.float32)
    for c in range(img.shape[2]):
        ch = np.ascontiguousarray(img[..., c])
        bg = cv2.morphologyEx(ch, cv2.MORPH_CLOSE, kernel)
        bg = np.maximum(cv2.GaussianBlur(bg, (0, 0), max(1.0, d_px / 2)), ch)
        # a black marker darkens every channel; contact shading darkens only some
        np.minimum(darkness, 1.0 - ch / np.maximum(bg, 1e-6), out=darkness)
    darkness = np.clip(darkness, 0.0, 1.0)
    blobs = (darkness > threshold).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(blobs, connectivity=8)
    min_area = max(1.0, 0.15 * np.pi * (d_px / 2) ** 2)
    max_area = 4.0 * np.pi * (d_px / 2 + 1) ** 2
    weights = np.clip(darkness - 0.5 * threshold, 0.0, None)
    centres: list[tuple[float, float]] = []
    pad = 1
    for i in range(1, n):
        x0, y0, w, h, area = stats[i]
        if area < min_area or area > max_area:
            continue
        r0, r1 = max(0, y0 - pad), min(img.shape[0], y0 + h + pad)
        c0, c1 = max(0, x0 - pad), min(img.shape[1], x0 + w + pad)
        win = weights[r0:r1, c0:c1] * (
            (labels[r0:r1, c0:c1] == i) | (labels[r0:r1, c0:c1] == 0)
        )
        total = float(win.sum())
        if total <= 0:
            continue
        # weighted centroid from the window's row and column sums (no index grids)
        rows = np.arange(r0, r1, dtype=np.float64)
        cols = np.arange(c0, c1, dtype=np.float64)
        centres.append((float(win.sum(axis=1) @ rows / total), float(win.sum(axis=0) @ cols / total)))
    rc = np.array(centres, np.float64).reshape(-1, 2)
    grow = max(1, int(round(d_px / 4)))
    mask = cv2.dilate(
        (darkness > 0.5 * threshold).astype(np.uint8),
        cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1)),
    ).astype(bool)
    # markers cover π(d/2)²/pitch² of the membrane (9 % for the paper's); a mask far larger
    # than that is reconstruction noise, and masking it would leave nothing to measure
    expected = np.pi * (params.marker_diameter_mm / 2) ** 2 / params.marker_pitch_mm**2
    if mask.mean() > min(0.6, 4.0 * expected + 0.1):
        mask[:] = False
    return MarkerDetection(params.px_to_mm(rc), mask, darkness)


@dataclass
class MarkerTracker:
    """Nearest-neighbour marker tracking cascaded to the reference frame.

    Each update matches the markers' predicted positions to the new detections by mutual
    nearest neighbour within ``max_step_mm``. A marker that is not found keeps its last
    position as "lost" (NaN in the output) and is predicted from the median motion of its
    visible neighbours, so it is picked up again when it reappears.

    Attributes
    ----------
    max_step_mm
        Largest accepted motion between consecutive frames (default: 0.45 × pitch).
    """

    max_step_mm: float = 0.675
    reference_mm: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    last_mm: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    visible: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    def reset(self, reference_mm: np.ndarray) -> None:
        """Start tracking from the reference marker positions (``K × 2`` mm)."""
        self.reference_mm = np.asarray(reference_mm, np.float64).reshape(-1, 2).copy()
        self.last_mm = self.reference_mm.copy()
        self.visible = np.ones(len(self.reference_mm), bool)

    def _predict(self) -> np.ndarray:
        pred = self.last_mm.copy()
        lost = ~self.visible
        if lost.any() and self.visible.sum() >= 3:
            vis_ref = self.reference_mm[self.visible]
            vis_disp = self.last_mm[self.visible] - vis_ref
            tree = cKDTree(vis_ref)
            k = min(4, len(vis_ref))
            _, idx = tree.query(self.reference_mm[lost], k=k)
            idx = np.asarray(idx).reshape(int(lost.sum()), k)
            pred[lost] = self.reference_mm[lost] + np.median(vis_disp[idx], axis=1)
        return pred

    def update(self, detections_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Match a frame's detections; returns ``(positions_mm, displacements_mm)``.

        Both are ``K × 2`` float32 in the reference order, NaN for markers not seen in
        this frame.
        """
        k = len(self.reference_mm)
        pos = np.full((k, 2), np.nan)
        det = np.asarray(detections_mm, np.float64).reshape(-1, 2)
        if k and len(det):
            pred = self._predict()
            d_tree = cKDTree(det)
            dist, j = d_tree.query(pred, k=1)
            p_tree = cKDTree(pred)
            _, back = p_tree.query(det, k=1)
            ok = (dist <= self.max_step_mm) & (back[j] == np.arange(k))
            pos[ok] = det[j[ok]]
            self.visible = ok
            self.last_mm[ok] = pos[ok]
        else:
            self.visible = np.zeros(k, bool)
        disp = pos - self.reference_mm
        return pos.astype(np.float32), disp.astype(np.float32)


def mean_shear(
    displacements_mm: np.ndarray, moving_mm: float = 0.05
) -> tuple[np.ndarray, float]:
    """Mean displacement of the markers that move, and its direction (paper: the test-tube
    insertion steers against it).

    A marker "moves" when its displacement exceeds both ``moving_mm`` and three times the
    median displacement of all markers (most markers are away from the contact, so the
    median measures the tracking noise).

    Parameters
    ----------
    displacements_mm
        ``K × 2`` (dx, dy) in mm, NaN rows (lost markers) ignored.
    moving_mm
        Smallest displacement that counts as motion; with no marker moving, or a mean
        shorter than half of it, there is no shear (direction NaN).

    Returns
    -------
    (mean_mm, direction_rad)
        ``(2,)`` mean displacement of the moving markers in mm and ``atan2(dy, dx)`` in
        radians.
    """
    d = np.asarray(displacements_mm, np.float64).reshape(-1, 2)
    d = d[np.isfinite(d).all(axis=1)]
    if len(d) == 0:
        return np.zeros(2), float("nan")
    mag = np.hypot(d[:, 0], d[:, 1])
    moving = mag >= max(moving_mm, 3.0 * float(np.median(mag)))
    if not moving.any():
        return np.zeros(2), float("nan")
    mean = d[moving].mean(axis=0)
    if float(np.hypot(*mean)) < 0.5 * moving_mm:
        return mean, float("nan")
    return mean, float(np.arctan2(mean[1], mean[0]))
