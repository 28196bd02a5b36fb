"""Scene-grid coordinates in mm (CONTRACTS §1: centred on the optical axis, x with columns,
y with rows) and the tactile parameters of a profile with their defaults."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from thintact_sdk.formats.profiles import Profile


@dataclass(frozen=True)
class TactileParams:
    """Tactile parameters of a profile (``profile.tactile``), defaults filled in.

    Attributes
    ----------
    rows, cols
        Scene grid N × M.
    mm_per_px
        Scene pixel size in mm (``tactile.mm_per_px``, else the scene pitch).
    contact_threshold_mm
        Depth above which a pixel is in contact (paper: 0.1 mm).
    marker_pitch_mm, marker_diameter_mm
        Marker lattice pitch and hole diameter (paper: 1.5 mm and 0.5 mm).
    elastomer_sigma_mm
        Gaussian smoothing that approximates the elastomer in the tactile simulation
        (``tactile.elastomer_sigma_mm``, default 0.25 mm).
    """

    rows: int
    cols: int
    mm_per_px: float
    contact_threshold_mm: float = 0.1
    marker_pitch_mm: float = 1.5
    marker_diameter_mm: float = 0.5
    elastomer_sigma_mm: float = 0.25

    @classmethod
    def from_profile(cls, profile: Profile) -> TactileParams:
        """Read ``profile.scene`` and ``profile.tactile`` (optional) into parameters."""
        t = profile.tactile
        mm_per_px = profile.scene.pixel_pitch_um / 1000.0
        kwargs: dict[str, float] = {}
        if t is not None:
            if t.mm_per_px is not None:
                mm_per_px = float(t.mm_per_px)
            kwargs = dict(
                contact_threshold_mm=float(t.contact_threshold_mm),
                marker_pitch_mm=float(t.marker_pitch_mm),
                marker_diameter_mm=float(t.marker_diameter_mm),
            )
            extra = t.model_extra or {}
            if "elastomer_sigma_mm" in extra:
                kwargs["elastomer_sigma_mm"] = float(extra["elastomer_sigma_mm"])
        return cls(rows=profile.scene.rows, cols=profile.scene.cols, mm_per_px=mm_per_px, **kwargs)

    def grid_mm(self) -> tuple[np.ndarray, np.ndarray]:
        """``(x_mm, y_mm)``, each ``N × M`` float64, pixel centres in mm."""
        return pixel_grid_mm(self.rows, self.cols, self.mm_per_px)

    def px_to_mm(self, rc: np.ndarray) -> np.ndarray:
        """``K × 2`` (row, col) pixel coordinates → ``K × 2`` (x, y) mm."""
        rc = np.asarray(rc, np.float64).reshape(-1, 2)
        x = (rc[:, 1] - (self.cols - 1) / 2) * self.mm_per_px
        y = (rc[:, 0] - (self.rows - 1) / 2) * self.mm_per_px
        return np.stack([x, y], axis=1)

    def mm_to_px(self, xy: np.ndarray) -> np.ndarray:
        """``K × 2`` (x, y) mm → ``K × 2`` (row, col) pixel coordinates."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        col = xy[:, 0] / self.mm_per_px + (self.cols - 1) / 2
        row = xy[:, 1] / self.mm_per_px + (self.rows - 1) / 2
        return np.stack([row, col], axis=1)


def pixel_grid_mm(rows: int, cols: int, mm_per_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates ``(x_mm, y_mm)`` (each ``rows × cols``) of a centred grid."""
    x = (np.arange(cols) - (cols - 1) / 2) * mm_per_px
    y = (np.arange(rows) - (rows - 1) / 2) * mm_per_px
    xx, yy = np.meshgrid(x, y)
    return xx, yy


def working_factor(params: TactileParams, max_work_mm: float = 0.13) -> int:
    """Integer binning factor f for tactile processing: the largest f dividing both grid
    sides with ``f · mm_per_px ≤ max_work_mm`` (1 when the grid is already that coarse).

    Photometric stereo and marker detection do not need the paper's 31.5 um pixels (the
    membrane blurs finer detail, paper §VI-B); working at ≈ 0.13 mm keeps a frame within the
    real-time budget.
    """
    best = 1
    for f in range(2, min(params.rows, params.cols) + 1):
        if f * params.mm_per_px > max_work_mm:
            break
        if params.rows % f == 0 and params.cols % f == 0:
            best = f
    return best


def binned_params(params: TactileParams, factor: int) -> TactileParams:
    """``params`` on the grid binned ``factor × factor`` (same field, same centre)."""
    if factor == 1:
        return params
    return replace(
        params, rows=params.rows // factor, cols=params.cols // factor,
        mm_per_px=params.mm_per_px * factor,
    )


def bin_image(image: np.ndarray, factor: int) -> np.ndarray:
    """Mean over ``factor × factor`` blocks: ``N × M (× C)`` → ``N/f × M/f (× C)`` float32
    (rows and columns past the last whole block are dropped).

    OpenCV's area resampling at an integer factor is exactly this block mean (to float32
    rounding) in one compiled pass, where numpy's mean over the block axes copies the image:
    it is a per-frame step of the tactile interpretation."""
    a = np.asarray(image, np.float32)
    if factor == 1:
        return a
    import cv2

    n, m = a.shape[0] // factor, a.shape[1] // factor
    if n == 0 or m == 0:
        return np.zeros((n, m) + a.shape[2:], np.float32)
    block = np.ascontiguousarray(a[: n * factor, : m * factor])
    out = np.asarray(cv2.resize(block, (m, n), interpolation=cv2.INTER_AREA), np.float32)
    return out.reshape((n, m) + a.shape[2:])


def upsample(image: np.ndarray, factor: int) -> np.ndarray:
    """Bilinear upsampling by ``factor`` (pixel centres aligned): inverse of :func:`bin_image`."""
    if factor == 1:
        return np.asarray(image, np.float32)
    import cv2

    a = np.ascontiguousarray(image, np.float32)
    return cv2.resize(a, (a.shape[1] * factor, a.shape[0] * factor), interpolation=cv2.INTER_LINEAR)
