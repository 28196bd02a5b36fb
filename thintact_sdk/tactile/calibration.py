"""Calibrating the photometric-stereo LUT from ball presses (paper: a 3 mm ball).

Two sources of ground-truth slopes:

* a ball of known radius pressed where the image says (real sensors, recordings): the
  contact circle is found in the colour change, and inside it the surface is the ball's
  cap, ∂d/∂x = −x/√(R² − r²) (x, r from the circle centre);
* the tactile simulator's own slopes (virtual sensors): the press is commanded, so the
  ground truth is known exactly, elastomer smoothing included.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from thintact_sdk.errors import CalibrationError
from thintact_sdk.profile import Profile
from thintact_sdk.tactile.grid import TactileParams, bin_image, binned_params, working_factor
from thintact_sdk.tactile.indenters import Sphere
from thintact_sdk.tactile.interpreter import colour_change, fill_masked
from thintact_sdk.tactile.markers import detect_markers
from thintact_sdk.tactile.photometric import PhotometricLUT, calibrate_lut
from thintact_sdk.tactile.simulate import TactileScene, TactileSimulator

CALIBRATION_BALL_RADIUS_MM = 1.5


@dataclass
class BallPress:
    """One calibration press: the image and what is known about its slopes.

    Attributes
    ----------
    image
        ``N × M × 3`` membrane image (reconstructed or simulated), display units.
    grad_x, grad_y
        ``N × M`` known slopes (mm per mm), or None to derive them from the ball model.
    """

    image: np.ndarray
    grad_x: np.ndarray | None = None
    grad_y: np.ndarray | None = None


def random_ball_presses(
    profile: Profile,
    count: int = 12,
    ball_radius_mm: float = CALIBRATION_BALL_RADIUS_MM,
    depth_range_mm: tuple[float, float] = (0.3, 1.0),
    seed: int = 0,
) -> list[tuple[TactileScene, dict[str, float]]]:
    """Simulated ball presses at random places and depths inside the field.

    Returns
    -------
    list of (scene, press)
        ``press`` holds ``x_mm``, ``y_mm``, ``depth_mm``, ``ball_radius_mm``.
    """
    sim = TactileSimulator.for_profile(profile)
    p = sim.params
    rng = np.random.default_rng(seed)
    half_w = (p.cols / 2) * p.mm_per_px - 1.5 * ball_radius_mm
    half_h = (p.rows / 2) * p.mm_per_px - 1.5 * ball_radius_mm
    out = []
    for _ in range(count):
        press = {
            "x_mm": float(rng.uniform(-half_w, half_w)),
            "y_mm": float(rng.uniform(-half_h, half_h)),
            "depth_mm": float(rng.uniform(*depth_range_mm)),
            "ball_radius_mm": ball_radius_mm,
        }
        scene = sim.press(Sphere(ball_radius_mm), press["depth_mm"], (press["x_mm"], press["y_mm"]))
        out.append((scene, press))
    return out


def ball_slopes(
    shape: tuple[int, int],
    center_rc: tuple[float, float],
    contact_radius_px: float,
    ball_radius_px: float,
    rim_fraction: float = 0.9,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Slopes of a ball's cap inside its contact circle.

    Parameters
    ----------
    shape
        ``(N, M)`` image size.
    center_rc
        (row, col) of the circle centre, px.
    contact_radius_px, ball_radius_px
        Contact circle and ball radius, px.
    rim_fraction
        Only pixels within this fraction of ``min(contact, 0.95·ball)`` radius are trusted
        (the rim is blurred by the elastomer and the slope diverges at r → R).

    Returns
    -------
    (grad_x, grad_y, inside)
        ``N × M`` slopes ∂d/∂x, ∂d/∂y (dimensionless) and the trusted-pixel mask.
    """
    rr, cc = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    x, y = cc - center_rc[1], rr - center_rc[0]
    r2 = x**2 + y**2
    radius = rim_fraction * min(contact_radius_px, 0.95 * ball_radius_px)
    inside = r2 < radius**2
    root = np.sqrt(np.clip(ball_radius_px**2 - r2, 1e-9, None))
    gx = np.where(inside, -x / root, 0.0)
    gy = np.where(inside, -y / root, 0.0)
    return gx, gy, inside


def find_press_circle(
    change: np.ndarray, marker_mask: np.ndarray | None = None, threshold: float | None = None
) -> tuple[tuple[float, float], float]:
    """Locate a ball press in a colour-change image.

    Parameters
    ----------
    change
        ``N × M × 3`` colour minus background.
    marker_mask
        Pixels to ignore (markers).
    threshold
        Colour-change magnitude that counts as contact; default: 6 × the median magnitude
        plus 0.02.

    Returns
    -------
    ((row, col), radius_px)
        Centre and radius of the circle with the contact blob's area.

    Raises
    ------
    CalibrationError
        When no contact blob is found.
    """
    mag = np.linalg.norm(change, axis=2).astype(np.float32)
    if marker_mask is not None:
        mag = fill_masked(mag, marker_mask, 2.0)
    mag = cv2.GaussianBlur(mag, (0, 0), 1.0)
    if threshold is None:
        threshold = 6.0 * float(np.median(mag)) + 0.02
    blob = (mag > threshold).astype(np.uint8)
    blob = cv2.morphologyEx(blob, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    n, labels, stats, cent = cv2.connectedComponentsWithStats(blob)
    if n < 2:
        raise CalibrationError("no press found in the frame: press the ball into the membrane")
    i = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    area = float(stats[i, cv2.CC_STAT_AREA])
    if area < 20:
        raise CalibrationError(f"press too small ({area:.0f} px): press the ball deeper")
    return (float(cent[i][1]), float(cent[i][0])), float(np.sqrt(area / np.pi))


def calibrate_from_presses(
    profile: Profile,
    reference: np.ndarray,
    presses: list[BallPress],
    ball_radius_mm: float = CALIBRATION_BALL_RADIUS_MM,
    bins: int = 32,
    meta: dict[str, Any] | None = None,
    max_work_mm: float = 0.13,
    smooth_px: float = 1.0,
) -> PhotometricLUT:
    """Calibrate a LUT from ball presses against a no-contact reference image.

    Parameters
    ----------
    profile
        The device (scene grid, pixel size, markers).
    reference
        ``N × M × 3`` no-contact image.
    presses
        Press images with known slopes, or without (ball model from the found circle).
    ball_radius_mm
        Radius of the calibration ball (used with the ball model).
    bins
        LUT nodes per colour axis.
    meta
        Extra provenance stored with the LUT.
    max_work_mm, smooth_px
        Work on the grid binned and smoothed as the interpreter does (same defaults).
    """
    full = TactileParams.from_profile(profile)
    factor = working_factor(full, max_work_mm)
    params = binned_params(full, factor)
    sigma = max(0.5, 0.3 * params.marker_diameter_mm / params.mm_per_px)
    reference = bin_image(reference, factor)
    ref_det = detect_markers(reference, params)
    background = fill_masked(reference, ref_det.mask, sigma)
    feats, gxs, gys, valids = [], [], [], []
    rng = np.random.default_rng(0)
    for press in presses:
        img = bin_image(press.image, factor)
        det = detect_markers(img, params)
        change = colour_change(img, background, det.mask, sigma, smooth_px)
        if press.grad_x is None or press.grad_y is None:
            center, radius_px = find_press_circle(change, det.mask)
            gx, gy, inside = ball_slopes(
                img.shape[:2], center, radius_px, ball_radius_mm / params.mm_per_px
            )
            rr, cc = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
            far = (rr - center[0]) ** 2 + (cc - center[1]) ** 2 > (1.6 * radius_px) ** 2
            flat = far & (rng.random(far.shape) < 0.1)
            valid = (inside | flat) & ~det.mask
        else:
            gx, gy = bin_image(press.grad_x, factor), bin_image(press.grad_y, factor)
            if smooth_px > 0:  # the slopes the smoothed colours stand for
                gx = cv2.GaussianBlur(gx, (0, 0), smooth_px)
                gy = cv2.GaussianBlur(gy, (0, 0), smooth_px)
            moving = np.hypot(gx, gy) > 1e-3
            valid = (moving | (rng.random(gx.shape) < 0.1)) & ~det.mask
        feats.append(change)
        gxs.append(gx)
        gys.append(gy)
        valids.append(valid)
    info = {
        "profile": profile.name,
        "profile_hash": profile.content_hash(),
        "presses": len(presses),
        "ball_radius_mm": ball_radius_mm,
        "slopes_from": "ball model" if presses and presses[0].grad_x is None else "simulator",
        "work_mm_per_px": params.mm_per_px,
    }
    info.update(meta or {})
    return calibrate_lut(feats, gxs, gys, valids, bins=bins, meta=info)


def scene_level_lut(profile: Profile, presses: int = 12, seed: int = 0) -> PhotometricLUT:
    """A LUT calibrated on the tactile simulator's own scenes (no lensless imaging):
    what a virtual sensor uses until ``thintact calibrate-tactile`` stores one."""
    sim = TactileSimulator.for_profile(profile)
    ref = sim.flat().scene
    data = random_ball_presses(profile, presses, seed=seed)
    items = [BallPress(s.scene, s.grad_x, s.grad_y) for s, _ in data]
    return calibrate_from_presses(profile, ref, items, meta={"source": "tactile-simulator"})
