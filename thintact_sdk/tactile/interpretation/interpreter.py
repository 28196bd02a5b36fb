"""Reconstructed membrane image → :class:`~thintact_sdk.frames.TactileFrame`.

Per frame: detect the markers (and mask them out), subtract the no-contact background,
map colour changes to slopes with the LUT, fill the masked pixels from their
neighbours, integrate the slopes to depth (Poisson), find the contact region in it, and track
the markers against the reference frame.
The contact region is where the membrane wraps the object
(:mod:`~thintact_sdk.tactile.interpretation.contact_region`), not everything deeper than the
contact threshold: a real gel's skirt around the contact is left out.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from thintact_sdk.formats.profiles import Profile
from thintact_sdk.frames import TactileFrame
from thintact_sdk.tactile.interpretation.colour_change import colour_change, fill_masked
from thintact_sdk.tactile.interpretation.contact_region import contact_region
from thintact_sdk.tactile.interpretation.force import ForceModel
from thintact_sdk.tactile.interpretation.grid import (
    TactileParams,
    bin_image,
    binned_params,
    upsample,
    working_factor,
)
from thintact_sdk.tactile.interpretation.markers import MarkerTracker, detect_markers, mean_shear
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT
from thintact_sdk.tactile.interpretation.poisson import Boundary, integrate_gradients
from thintact_sdk.tactile.interpretation.slip import estimate_slip_ratio


class TactileInterpreter:
    """Turns reconstructed images of one sensor into tactile frames.

    Parameters
    ----------
    profile
        Supplies the scene grid, pixel size, contact threshold and marker geometry.
    lut
        Photometric-stereo table; without one the depth is all zeros and
        ``frame.meta["depth"] == "no LUT"``.
    marker_threshold
        Relative darkness that starts a marker (see
        :func:`thintact_sdk.tactile.interpretation.markers.detect_markers`).
    min_contact_area_mm2
        Smallest region above the contact threshold that counts as contact.
    max_work_mm
        Photometric stereo and marker detection run on the scene grid binned to about this
        pixel size (:func:`~thintact_sdk.tactile.interpretation.grid.working_factor`); the depth map is
        returned on the full grid.
    smooth_px
        Gaussian smoothing (working-grid pixels) of the colour change before the LUT.
    reference_frames
        Without :meth:`set_reference`, the mean of the first this-many images becomes the
        reference (reconstruction noise in the reference would bias every frame).
    translator
        Applied to every image on the working grid before anything else (Real2Sim: real
        images made simulation-like, :class:`~thintact_sdk.tactile.learning.Real2SimTranslator`);
        ``H × W × 3`` in [0, 1] → the same.
    boundary
        Poisson integration's boundary (:func:`~thintact_sdk.tactile.interpretation.poisson.integrate_gradients`):
        ``"free"`` (no assumption at the frame's edge; depth 0 where the membrane is flat) or
        ``"zero"`` (depth pinned to 0 at the frame's edge).

    The first image interpreted becomes the reference (no-contact) frame unless
    :meth:`set_reference` is called first.
    """

    def __init__(
        self,
        profile: Profile,
        lut: PhotometricLUT | None = None,
        marker_threshold: float = 0.3,
        min_contact_area_mm2: float = 0.1,
        max_work_mm: float = 0.13,
        smooth_px: float = 1.0,
        reference_frames: int = 1,
        translator: Callable[[np.ndarray], np.ndarray] | None = None,
        boundary: Boundary = "free",
    ) -> None:
        self.params = TactileParams.from_profile(profile)
        self.factor = working_factor(self.params, max_work_mm)
        self.work = binned_params(self.params, self.factor)
        self.lut = lut
        if lut is not None and lut.net is not None and lut.net.shape != (self.work.rows,
                                                                         self.work.cols):
            from thintact_sdk.errors import CalibrationError

            raise CalibrationError(
                f"the tactile calibration's gradient network works on a {lut.net.shape[0]}×"
                f"{lut.net.shape[1]} grid, profile {profile.name!r} on {self.work.rows}×"
                f"{self.work.cols}: run `thintact calibrate-tactile --profile {profile.name}`")
        self.contact_rim_mm = float(lut.meta.get("contact_rim_mm", 0.0)) if lut is not None else 0.0
        """How far (mm) contact regions are grown past the curvature's sign change: the
        calibration's ``contact_rim_mm`` (how far the sensor's smoothing moves it inside the
        rim; :mod:`~thintact_sdk.tactile.interpretation.contact_region`), 0 without one."""
        self.smooth_px = smooth_px
        self.marker_threshold = marker_threshold
        self.min_contact_area_mm2 = min_contact_area_mm2
        self.tracker = MarkerTracker(max_step_mm=0.45 * self.params.marker_pitch_mm)
        self.force_model = ForceModel.from_profile(profile)
        self._sigma_px = max(0.5, 0.3 * self.work.marker_diameter_mm / self.work.mm_per_px)
        self.background: np.ndarray | None = None
        self.reference_markers_mm = np.zeros((0, 2))
        self.reference_frames = max(1, int(reference_frames))
        self._ref_sum: np.ndarray | None = None
        self._ref_count = 0
        self.translator = translator
        self.boundary: Boundary = boundary

    @classmethod
    def for_profile(cls, profile: Profile, **options: Any) -> TactileInterpreter:
        """An interpreter with the device's LUT (or, for a virtual device without one, a LUT
        calibrated on the tactile simulator; see
        :func:`thintact_sdk.tactile.calibration.store.lut_for_profile`)."""
        from thintact_sdk.tactile.calibration.store import lut_for_profile

        if profile.tactile is not None and profile.tactile.real2sim and "translator" not in options:
            from thintact_sdk.tactile.learning.translate import Real2SimTranslator

            options["translator"] = Real2SimTranslator.load(
                profile.resolve_path(profile.tactile.real2sim))
        return cls(profile, lut_for_profile(profile), **options)

    @property
    def has_reference(self) -> bool:
        return self.background is not None

    def _accumulate_reference(self, image: np.ndarray) -> None:
        acc = image.astype(np.float64)
        self._ref_sum = acc if self._ref_sum is None else self._ref_sum + acc
        self._ref_count += 1
        total, count = self._ref_sum, self._ref_count
        self.set_reference((total / count).astype(np.float32))
        self._ref_sum, self._ref_count = total, count  # set_reference ends accumulation

    def set_reference(self, image: np.ndarray) -> None:
        """Use ``image`` (``N × M × 3``, no contact) as background and marker reference."""
        img = self._work_image(self._check(image))
        det = detect_markers(img, self.work, self.marker_threshold)
        self.background = fill_masked(img, det.mask, self._sigma_px)
        self.reference_markers_mm = det.positions_mm
        self.tracker.reset(det.positions_mm)
        self._ref_sum, self._ref_count = None, self.reference_frames

    def _check(self, image: np.ndarray) -> np.ndarray:
        img = np.asarray(image, np.float32)
        want = (self.params.rows, self.params.cols, 3)
        if img.shape != want:
            from thintact_sdk.errors import ThinTactError

            raise ThinTactError(
                f"tactile interpreter expects {want[0]}×{want[1]}×3 images (the profile's scene "
                f"grid), got {'×'.join(map(str, img.shape))}"
            )
        return img

    def _work_image(self, full: np.ndarray) -> np.ndarray:
        """The image binned to the working grid, translated when a translator is set."""
        img = bin_image(full, self.factor)
        return img if self.translator is None else self.translator(img)

    def _work_slopes(
        self, img: np.ndarray, marker_mask: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(grad_x, grad_y, depth)`` on the working grid from a working-grid image (depth
        in mm, ≥ 0)."""
        if self.background is None:
            raise RuntimeError("set_reference() before asking for depth")
        if self.lut is None:
            zero = np.zeros(img.shape[:2], np.float32)
            return zero, zero, zero
        change = colour_change(img, self.background, marker_mask, self._sigma_px, self.smooth_px)
        # the network sees the colour with the markers filled in (background + change), never
        # the raw marker pixels
        colour = self.background + change if self.lut.net is not None else None
        gx, gy = self.lut.lookup(change, colour)
        depth = integrate_gradients(gx, gy, self.work.mm_per_px, self.boundary)
        return gx, gy, np.clip(depth, 0.0, None)

    def _work_depth(self, img: np.ndarray, marker_mask: np.ndarray | None) -> np.ndarray:
        """Depth (mm, ≥ 0) on the working grid from a working-grid image."""
        return self._work_slopes(img, marker_mask)[2]

    def work_slopes(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(grad_x, grad_y, depth)`` of one full-grid image on the working grid
        (:attr:`work`: slopes mm per mm, depth mm ≥ 0), for evaluation."""
        img = self._work_image(self._check(image))
        det = detect_markers(img, self.work, self.marker_threshold)
        return self._work_slopes(img, det.mask)

    def depth_from_image(self, image: np.ndarray) -> np.ndarray:
        """Depth map (``N × M`` float32 mm, ≥ 0) of one image against the reference."""
        img = self._work_image(self._check(image))
        det = detect_markers(img, self.work, self.marker_threshold)
        return upsample(self._work_depth(img, det.mask), self.factor)

    def contact(self, depth_mm: np.ndarray) -> tuple[bool, float, np.ndarray]:
        """``(contact, area_mm2, mask)`` of a depth map on the full grid (``N × M`` mm): the
        contact region of :func:`~thintact_sdk.tactile.interpretation.contact_region.contact_region`
        (where the membrane wraps the object, its skirt left out; grown by
        :attr:`contact_rim_mm`), contact when it covers at least ``min_contact_area_mm2``."""
        return self._contact(depth_mm, self.params.mm_per_px)

    def _contact(self, depth_mm: np.ndarray, mm_per_px: float) -> tuple[bool, float, np.ndarray]:
        mask = contact_region(depth_mm, mm_per_px, self.params.contact_threshold_mm,
                              self.work.mm_per_px, self.contact_rim_mm)
        area = float(mask.sum()) * mm_per_px**2
        return area >= self.min_contact_area_mm2, area, mask

    def interpret(
        self, image: np.ndarray, timestamp_ns: int = 0, frame_id: int = 0
    ) -> TactileFrame:
        """Interpret one reconstructed image (``N × M × 3`` display units)."""
        t0 = time.perf_counter()
        full = self._check(image)
        if self.background is None or 0 < self._ref_count < self.reference_frames:
            self._accumulate_reference(full)
        img = self._work_image(full)
        det = detect_markers(img, self.work, self.marker_threshold)
        work_depth = self._work_depth(img, det.mask)
        # the contact region on the working grid: the curvature it reads is no finer there
        contact, area, _ = self._contact(work_depth, self.work.mm_per_px)
        depth = upsample(work_depth, self.factor)
        pos, disp = self.tracker.update(det.positions_mm)
        shear, direction = mean_shear(disp)
        meta: dict[str, object] = {
            "markers_detected": int(len(det.positions_mm)),
            "markers_tracked": int(np.isfinite(pos[:, 0]).sum()) if len(pos) else 0,
            "interpret_ms": (time.perf_counter() - t0) * 1e3,
        }
        if self.lut is None:
            meta["depth"] = "no LUT"
        loads = (depth, self.params.mm_per_px, self.params.contact_threshold_mm,
                 self.tracker.reference_mm, disp)
        return TactileFrame(
            image=full,
            depth_mm=depth,
            marker_positions_mm=pos,
            marker_displacements_mm=disp,
            contact=contact,
            contact_area_mm2=area,
            timestamp_ns=int(timestamp_ns),
            frame_id=int(frame_id),
            shear_direction_rad=direction,
            shear_mm=np.asarray(shear, np.float64),
            meta=meta,
            force_n=self.force_model.estimate(*loads),
            slip_ratio=estimate_slip_ratio(*loads) if contact else None,
        )
