"""Tactile scene simulation: what the membrane shows when something presses on it.

Paper §VI-C: the rigid indentation of the indenter is smoothed by a Gaussian to
approximate the elastomer (over the gel beyond the frame too,
:mod:`~thintact_sdk.tactile.simulation.elastomer`), then shaded by Phong under the LEDs. Here the white membrane
also carries black markers that move with the load:

* shear: every marker moves by ``shear_mm`` weighted by how much of the contact patch
  (smoothed by ``shear_spread_mm``) it sits under, so markers in contact move with the
  indenter and the motion fades outside;
* normal load: markers are drawn towards the contact by ``normal_drag_mm`` times the
  slope of the depth smoothed over 1 mm.

The result is a scene on the profile's grid (``N × M × 3`` float32 in [0, 1]) and its
ground truth (depth in mm, gradients, marker positions in mm).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import map_coordinates

from thintact_sdk.formats.profiles import Profile
from thintact_sdk.tactile.interpretation.grid import TactileParams
from thintact_sdk.tactile.interpretation.markers import marker_coverage, marker_lattice_mm
from thintact_sdk.tactile.simulation.elastomer import GelWindow, gel_window, reach_px, smooth
from thintact_sdk.tactile.simulation.indenters import Indenter
from thintact_sdk.tactile.simulation.lighting import PhongShading

BROAD_MM = 1.0
"""Width (σ, mm) over which the depth is smoothed for the normal-load drag of the markers."""


@dataclass
class TactileScene:
    """A simulated tactile scene and its ground truth.

    Attributes
    ----------
    scene
        ``N × M × 3`` float32 membrane image in [0, 1] (display units).
    depth_mm
        ``N × M`` float32 indentation depth in mm (after elastomer smoothing).
    grad_x, grad_y
        ``N × M`` float32 slopes ∂d/∂x, ∂d/∂y (mm per mm).
    marker_reference_mm
        ``K × 2`` float64 (x, y) marker centres of the unloaded membrane, mm.
    marker_positions_mm
        ``K × 2`` float64 marker centres under this load, mm.
    """

    scene: np.ndarray
    depth_mm: np.ndarray
    grad_x: np.ndarray
    grad_y: np.ndarray
    marker_reference_mm: np.ndarray
    marker_positions_mm: np.ndarray

    @property
    def marker_displacements_mm(self) -> np.ndarray:
        """``K × 2`` ground-truth displacement of each marker, mm."""
        return self.marker_positions_mm - self.marker_reference_mm


@dataclass
class TactileSimulator:
    """Renders tactile scenes on a profile's scene grid.

    Parameters
    ----------
    params
        Grid and tactile parameters (:meth:`TactileParams.from_profile`).
    shading
        LED layout and reflectance (default: the 10-LED layout of
        :mod:`thintact_sdk.tactile.simulation.lighting`).
    marker_albedo
        Reflectance of the black marker paint.
    markers
        Whether to draw markers at all.
    shear_spread_mm, normal_drag_mm
        Marker-motion model (see module docstring).
    """

    params: TactileParams
    shading: PhongShading = field(default_factory=PhongShading)
    marker_albedo: float = 0.05
    markers: bool = True
    shear_spread_mm: float = 1.5
    normal_drag_mm: float = 0.3

    @classmethod
    def for_profile(cls, profile: Profile, **kwargs: object) -> TactileSimulator:
        """A simulator on ``profile``'s scene grid with its tactile parameters."""
        return cls(TactileParams.from_profile(profile), **kwargs)  # type: ignore[arg-type]

    def reference_markers_mm(self) -> np.ndarray:
        """``K × 2`` marker centres of the unloaded membrane (mm)."""
        if not self.markers:
            return np.zeros((0, 2))
        return marker_lattice_mm(self.params)

    def render(self, depth_mm: np.ndarray, marker_positions_mm: np.ndarray) -> np.ndarray:
        """Shade a membrane with the given (smoothed) depth and marker positions.

        Returns
        -------
        numpy.ndarray
            ``N × M × 3`` float32 scene in [0, 1].
        """
        gx, gy = self.gradients(depth_mm)
        albedo = np.ones_like(gx)
        if len(marker_positions_mm):
            cov = marker_coverage(marker_positions_mm, self.params)
            albedo = 1.0 - (1.0 - self.marker_albedo) * cov
        return self.shading.shade(gx, gy, albedo)

    def gradients(self, depth_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Slopes ``(∂d/∂x, ∂d/∂y)`` of a depth map (central differences), each ``N × M``."""
        gy, gx = np.gradient(np.asarray(depth_mm, np.float64), self.params.mm_per_px)
        return np.asarray(gx), np.asarray(gy)

    def flat(self) -> TactileScene:
        """The unloaded membrane (the reference frame)."""
        z = np.zeros((self.params.rows, self.params.cols))
        ref = self.reference_markers_mm()
        return self._scene(z, ref, ref)

    def press(
        self,
        indenter: Indenter,
        depth_mm: float,
        center_mm: tuple[float, float] = (0.0, 0.0),
        angle_deg: float = 0.0,
        shear_mm: tuple[float, float] = (0.0, 0.0),
    ) -> TactileScene:
        """Press ``indenter`` ``depth_mm`` into the membrane.

        Parameters
        ----------
        indenter
            Shape (see :mod:`thintact_sdk.tactile.simulation.indenters`).
        depth_mm
            Press depth of the rigid tip below the membrane, mm (paper: 0.25-1.00).
        center_mm
            (x, y) of the tip centre in mm.
        angle_deg
            Rotation of the indenter about the press axis, degrees.
        shear_mm
            (x, y) tangential displacement of the contact patch, mm.
        """
        p = self.params
        sigma_px = p.elastomer_sigma_mm / p.mm_per_px
        ref = self.reference_markers_mm()
        spread_px, broad_px = self._marker_smoothing_px() if len(ref) else (0.0, 0.0)

        def rigid_at(rr: np.ndarray, cc: np.ndarray) -> np.ndarray:
            x = (cc - (p.cols - 1) / 2) * p.mm_per_px
            y = (rr - (p.rows - 1) / 2) * p.mm_per_px
            return indenter.indentation_mm(x, y, depth_mm, center_mm, angle_deg)

        # the gel and the indenter go on beyond the frame: every smoothing below (the
        # elastomer's, the marker model's of the contact and, after the elastomer's, of the
        # depth; without markers, the elastomer's alone) sees the true shape past the edge
        rigid, win = gel_window(rigid_at, (p.rows, p.cols),
                                max(reach_px(sigma_px) + reach_px(broad_px), reach_px(spread_px)),
                                grow=reach_px(sigma_px))
        smoothed = smooth(rigid, sigma_px)
        moved = ref + self._marker_motion(rigid, smoothed, win, ref,
                                          np.asarray(shear_mm, np.float64))
        return self._scene(win.frame(smoothed), ref, moved)

    def _marker_smoothing_px(self) -> tuple[float, float]:
        """Widths (σ, px) of the marker model's smoothings: of the contact (shear spread) and
        of the depth (normal-load drag)."""
        return (self.shear_spread_mm / self.params.mm_per_px,
                BROAD_MM / self.params.mm_per_px)

    def _marker_motion(
        self, rigid: np.ndarray, depth: np.ndarray, win: GelWindow, ref_mm: np.ndarray,
        shear_mm: np.ndarray,
    ) -> np.ndarray:
        """Marker displacements (``K × 2`` mm) for ``rigid`` and smoothed ``depth`` on the
        gel window ``win`` around the frame."""
        if len(ref_mm) == 0:
            return np.zeros((0, 2))
        p = self.params
        spread_px, broad_px = self._marker_smoothing_px()
        contact = (rigid > 0).astype(np.float64)
        weight = smooth(contact, spread_px)
        if weight.max() > 0:
            weight = np.clip(weight / max(0.5, float(weight.max())), 0.0, 1.0)
        broad = smooth(depth, broad_px)
        by, bx = np.gradient(broad, p.mm_per_px)
        rc = p.mm_to_px(ref_mm).T + np.asarray(win.origin, np.float64)[:, None]
        w = map_coordinates(weight, rc, order=1, mode="nearest")
        sx = map_coordinates(bx, rc, order=1, mode="nearest")
        sy = map_coordinates(by, rc, order=1, mode="nearest")
        motion = w[:, None] * shear_mm[None, :]
        motion += self.normal_drag_mm * np.stack([sx, sy], axis=1)
        return motion

    def _scene(self, depth: np.ndarray, ref: np.ndarray, moved: np.ndarray) -> TactileScene:
        gx, gy = self.gradients(depth)
        return TactileScene(
            scene=self.render(depth, moved),
            depth_mm=depth.astype(np.float32),
            grad_x=gx.astype(np.float32),
            grad_y=gy.astype(np.float32),
            marker_reference_mm=ref.copy(),
            marker_positions_mm=moved,
        )


def simulate_press(
    profile: Profile,
    indenter: Indenter,
    depth_mm: float,
    center_mm: tuple[float, float] = (0.0, 0.0),
    angle_deg: float = 0.0,
    shear_mm: tuple[float, float] = (0.0, 0.0),
) -> TactileScene:
    """One press scene + ground truth on ``profile``'s scene grid (see :class:`TactileSimulator`)."""
    return TactileSimulator.for_profile(profile).press(
        indenter, depth_mm, center_mm, angle_deg, shear_mm
    )
