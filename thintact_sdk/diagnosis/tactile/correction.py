"""What the fitted tactile model buys photometric stereo, with no real ground truth used.

* **Fitted-simulation LUT**: ball presses simulated with the fitted model (lights, lobe,
  elastomer blur, illumination field, texture, camera response), their colour change against
  the simulated no-contact frame, calibrated against the simulator's exact slopes; applied to
  real frames minus the real no-contact frame.
* **Physics correction**: each real frame is taken back through the named effects before
  photometric stereo: the camera response inverted (``I^(1/γ)``), divided by the fitted
  background ``F·(1 + α t)`` and by the frame's exposure (median over pixels far from the
  press, found in the image), leaving the shading ``S`` (1 where flat); the LUT is calibrated
  on ``S − 1`` of presses simulated with the fitted lights, lobe and blur.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thintact_sdk.diagnosis.tactile.press_model import (
    Press,
    TactileModel,
    ball_normals,
    polynomial_basis,
    texture_map,
)
from thintact_sdk.errors import CalibrationError
from thintact_sdk.tactile.calibration.ball_press import find_press_circle
from thintact_sdk.tactile.calibration.gelsight_eval import (
    GELSIGHT_BALL_RADIUS_MM,
    GELSIGHT_MM_PER_PX,
    evaluate_images,
    load_pack,
)
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT, calibrate_lut


@dataclass
class CorrectionRow:
    """One row of the held-out table (slope RMS in mm/mm, depth RMS in mm)."""

    method: str
    slope_rms: float
    depth_rms_mm: float


def _background(model: TactileModel, reference: np.ndarray) -> np.ndarray:
    h, w = reference.shape[:2]
    basis = polynomial_basis(h, w, model.field_order)
    return model.background(basis, texture_map(reference.astype(np.float64)))


def fitted_presses(model: TactileModel, shape: tuple[int, int], ball_radius_mm: float,
                   mm_per_px: float, count: int = 48, depth_range_mm: tuple[float, float] = (0.2, 1.8),
                   seed: int = 1) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """Shading ``S`` (``H × W × 3``, 1 flat) and exact slopes of ``count`` simulated ball
    presses at random places (the ball inside the field) and depths, under ``model``."""
    rng = np.random.default_rng(seed)
    r_px = ball_radius_mm / mm_per_px
    shades, gxs, gys = [], [], []
    for _ in range(count):
        p = Press(float(rng.uniform(r_px, shape[0] - r_px)), float(rng.uniform(r_px, shape[1] - r_px)),
                  float(rng.uniform(*depth_range_mm)))
        nrm = ball_normals(shape, p, ball_radius_mm, mm_per_px, model.sigma_mm, model.skirt_mm)
        shades.append(model.shading(nrm))
        gxs.append(nrm.gx)
        gys.append(nrm.gy)
    return shades, gxs, gys


def fitted_images(model: TactileModel, reference: np.ndarray, ball_radius_mm: float,
                  mm_per_px: float, count: int = 48, depth_range_mm: tuple[float, float] = (0.2, 1.8),
                  seed: int = 1) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """The fitted simulation's camera images: its no-contact frame and ``count`` ball presses
    (:func:`fitted_presses`), each the camera response to background × shading, in display
    units (``H × W × 3``, [0, 1] before clipping), with the presses' exact slopes.

    ``reference`` (``H × W × 3``, display units) is the real no-contact frame the fitted
    background's texture comes from.

    Returns
    -------
    (flat, images, grad_x, grad_y)
    """
    bg = _background(model, reference)
    shades, gxs, gys = fitted_presses(model, reference.shape[:2], ball_radius_mm, mm_per_px,
                                      count, depth_range_mm, seed)
    return model.respond(bg), [model.respond(bg * s) for s in shades], gxs, gys


def _lut(changes: list[np.ndarray], gxs: list[np.ndarray], gys: list[np.ndarray], bins: int,
         source: str, seed: int = 0) -> PhotometricLUT:
    rng = np.random.default_rng(seed)
    valid = [(np.hypot(gx, gy) > 1e-3) | (rng.random(gx.shape) < 0.1) for gx, gy in zip(gxs, gys, strict=True)]
    return calibrate_lut(changes, gxs, gys, valid, bins=bins, meta={"source": source})


def fitted_simulation_lut(model: TactileModel, reference: np.ndarray, ball_radius_mm: float,
                          mm_per_px: float, bins: int = 24) -> PhotometricLUT:
    """LUT of the fitted simulation's full images (colour change against its flat frame)."""
    flat, images, gxs, gys = fitted_images(model, reference, ball_radius_mm, mm_per_px)
    return _lut([im - flat for im in images], gxs, gys, bins, "fitted tactile simulation")


def shading_lut(model: TactileModel, shape: tuple[int, int], ball_radius_mm: float,
                mm_per_px: float, bins: int = 24) -> PhotometricLUT:
    """LUT of the fitted shading alone (``S − 1``), for corrected frames."""
    shades, gxs, gys = fitted_presses(model, shape, ball_radius_mm, mm_per_px)
    return _lut([s - 1.0 for s in shades], gxs, gys, bins, "fitted tactile shading")


def correct_frames(model: TactileModel, images: np.ndarray, reference: np.ndarray,
                   ball_radius_mm: float, mm_per_px: float) -> np.ndarray:
    """Invert the named effects: ``P × H × W × 3`` shading estimates (1 where flat).

    The exposure of each frame is the per-channel median of ``I^(1/γ) / background`` over
    pixels beyond 2.5 ball radii of the press circle found in the frame (no annotation used).
    """
    bg = _background(model, reference)
    g = model.gamma
    out = np.empty(images.shape)
    h, w = images.shape[1:3]
    rr, cc = np.mgrid[0:h, 0:w]
    for i, img in enumerate(images):
        lin = np.clip(img.astype(np.float64), 1e-3, None) ** (1.0 / g)
        ratio = lin / np.maximum(bg, 1e-3)
        try:
            (row, col), _ = find_press_circle(img - reference)
            far = np.hypot(rr - row, cc - col) > 2.5 * ball_radius_mm / mm_per_px
        except CalibrationError:
            far = np.ones((h, w), bool)
        expo = np.median(ratio[far], axis=0) if far.sum() > 100 else np.median(ratio, axis=(0, 1))
        out[i] = ratio / np.maximum(expo, 1e-3)
    return out


def evaluate_correction(pack_path: str | Path, model: TactileModel, bins: int = 24
                        ) -> list[CorrectionRow]:
    """The held-out table on the odd presses (LUTs from the even ones or from the fitted model
    only): plain real LUT, fitted-simulation LUT, physics correction."""
    pack = load_pack(pack_path)
    images = pack["imgs"].astype(np.float64) / 255.0
    f0 = pack["f0"].astype(np.float64) / 255.0
    r, mpp = GELSIGHT_BALL_RADIUS_MM, GELSIGHT_MM_PER_PX
    rows = []
    plain = evaluate_images(pack, images, f0, None, bins)
    rows.append(CorrectionRow("real LUT (annotated caps of the even presses)", plain.grad_rms,
                              plain.depth_rms_mm))
    lut = fitted_simulation_lut(model, f0, r, mpp, bins)
    ev = evaluate_images(pack, images, f0, None, bins, lut=lut)
    rows.append(CorrectionRow("fitted-simulation LUT (no real ground truth)", ev.grad_rms,
                              ev.depth_rms_mm))
    corrected = correct_frames(model, images, f0, r, mpp)
    lut_s = shading_lut(model, f0.shape[:2], r, mpp, bins)
    ev = evaluate_images(pack, corrected, np.ones_like(f0), None, bins, lut=lut_s)
    rows.append(CorrectionRow("physics correction + fitted-shading LUT (no real ground truth)",
                              ev.grad_rms, ev.depth_rms_mm))
    ev = evaluate_images(pack, corrected, np.ones_like(f0), None, bins)
    rows.append(CorrectionRow("physics correction + LUT on corrected even presses (annotated caps)",
                              ev.grad_rms, ev.depth_rms_mm))
    return rows
