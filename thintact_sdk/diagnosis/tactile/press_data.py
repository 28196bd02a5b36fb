"""Reading real tactile presses for the diagnosis, the per-pixel noise and first nuisances.

Input: a ``dataPack``-style ``.npz`` (``imgs`` P×H×W×3, ``f0`` the no-contact frame; Taxim's
GelSight pack) or a directory holding exactly one. Annotations in the pack (contact circles)
are never used by the diagnosis: press centres and depths come from the images.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

from thintact_sdk.diagnosis.tactile.press_model import Press
from thintact_sdk.errors import CalibrationError, ThinTactError
from thintact_sdk.tactile.calibration.ball_press import find_press_circle
from thintact_sdk.tactile.learning.domains import RealPresses


def load_presses(path: str | Path) -> RealPresses:
    """Real presses from a pack file or a directory with one pack.

    Raises
    ------
    ThinTactError
        Missing path, no or several ``.npz`` in a directory, or not a press pack.
    """
    p = Path(path)
    if p.is_dir():
        packs = sorted(p.glob("*.npz"))
        if len(packs) != 1:
            raise ThinTactError(f"{p}: expected one press pack (.npz with imgs and f0), "
                                f"found {len(packs)}")
        p = packs[0]
    if not p.exists():
        raise ThinTactError(f"{p}: no such file")
    real = RealPresses.from_pack(p)
    if len(real.images) < 2:
        raise ThinTactError(f"{p}: needs at least 2 presses, got {len(real.images)}")
    return real


def initial_presses(images: np.ndarray, reference: np.ndarray, ball_radius_mm: float,
                    mm_per_px: float) -> list[Press]:
    """First nuisances from the images alone: the press circle in the colour change
    (:func:`thintact_sdk.tactile.calibration.ball_press.find_press_circle`, after a 1.5 px blur) and the depth of a ball cap
    with that contact radius.

    Raises
    ------
    ThinTactError
        A frame without a visible press (names its index).
    """
    out = []
    for i, img in enumerate(images):
        try:
            change = gaussian_filter(img - reference, (1.5, 1.5, 0))  # per-pixel noise down
            (row, col), radius_px = find_press_circle(change)
        except CalibrationError as exc:
            raise ThinTactError(f"press {i}: {exc}") from None
        a = min(radius_px * mm_per_px, 0.9 * ball_radius_mm)
        depth = ball_radius_mm - np.sqrt(ball_radius_mm**2 - a * a)
        out.append(Press(row, col, float(np.clip(depth, 0.05, 0.9 * ball_radius_mm))))
    return out


def estimate_noise(images: np.ndarray, presses: list[Press], ball_radius_mm: float,
                   mm_per_px: float) -> np.ndarray:
    """Per-channel per-pixel noise σ (display units) from repeat frames: consecutive presses
    compared where both are flat (beyond 2.5 ball radii of either press), each frame's gain
    matched first; robust (MAD) standard deviation / √2.

    Raises
    ------
    ThinTactError
        When no two frames share enough flat pixels.
    """
    h, w = images.shape[1:3]
    rr, cc = np.mgrid[0:h, 0:w]
    far_px = 2.5 * ball_radius_mm / mm_per_px
    far = [np.hypot(rr - p.row, cc - p.col) > far_px for p in presses]
    diffs = []
    for i in range(len(images) - 1):
        m = far[i] & far[i + 1]
        if m.sum() < 100:
            continue
        a, b = images[i][m], images[i + 1][m]
        gain = np.median(a, axis=0) / np.maximum(np.median(b, axis=0), 1e-6)
        diffs.append(a - gain * b)
    if not diffs:
        raise ThinTactError("cannot measure the noise: no two frames share flat pixels")
    d = np.concatenate(diffs)
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return np.maximum(1.4826 * mad / np.sqrt(2.0), 0.5 / 255)
