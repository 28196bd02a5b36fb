"""Scene-grid coordinates in mm (CONTRACTS §1: centred on the optical axis, x with columns,
y with rows) and the tactile parameters of a profile with their defaults."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thintact_sdk.profile import Profile


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
