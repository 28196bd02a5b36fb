"""Photometric stereo on real GelSight ball presses (Taxim ``dataPack_small.npz``, MIT).

The pack holds 49 presses of a 2.00 mm-radius ball on a marker-free GelSight at
0.1245 mm/px (160 × 120), a no-contact frame ``f0`` and a hand-annotated contact circle
per press (``touch_center`` = [x (col), y (row)], ``touch_radius`` px). Inside the circle
the ball cap's slopes are known (∂d/∂x = −x/√(R² − r²)); the depth the annotation implies
is not reliable (the annotated radius ≈ R), so the depth figure reported here compares
the depth integrated from the LUT's slopes with the depth integrated, the same way, from
the ball-model slopes: it measures what slope errors do to depth, not absolute depth.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thintact_sdk.formats.safe_arrays import ArrayFileError, read_npz
from thintact_sdk.tactile.calibration.ball_press import ball_slopes
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT, calibrate_lut
from thintact_sdk.tactile.interpretation.poisson import integrate_gradients

GELSIGHT_MM_PER_PX = 0.1245
GELSIGHT_BALL_RADIUS_MM = 2.0
PACK_MEMBERS = ("imgs", "f0", "touch_center", "touch_radius")
"""The members of a press pack the evaluation reads (others, like ``names``, are kept)."""


@dataclass
class GelSightEvaluation:
    """Figures of a LUT calibrated on some presses and tested on the others.

    Attributes
    ----------
    train, test
        Press indices used for calibration and for testing.
    grad_rms
        RMS slope error (mm per mm, vector magnitude) inside the test circles.
    grad_rms_zero
        The same for a predictor that always says "flat" (for scale).
    depth_rms_mm
        RMS depth difference inside the test circles between LUT-slope depth and
        ball-model-slope depth (both Poisson-integrated).
    depth_peak_mm
        Mean peak depth of the ball-model-slope depth (for scale).
    """

    train: list[int]
    test: list[int]
    grad_rms: float
    grad_rms_zero: float
    depth_rms_mm: float
    depth_peak_mm: float
    lut: PhotometricLUT


def load_pack(path: str | Path) -> dict[str, np.ndarray]:
    """Every array of ``dataPack_small.npz`` (its ``names`` are a plain unicode array).

    Read with :func:`thintact_sdk.formats.safe_arrays.read_npz`: never unpickles.

    Raises
    ------
    ThinTactError
        Naming the file and member: not an ``.npz``, damaged, a pickled (object) member, a
        missing or non-numeric ``imgs``, ``f0``, ``touch_center`` or ``touch_radius``, or
        declared sizes beyond the memory there is.
    """
    pack = read_npz(path, what="press pack", kinds=dict.fromkeys(PACK_MEMBERS, "uif"))
    missing = [k for k in PACK_MEMBERS if k not in pack]
    if missing:
        raise ArrayFileError(f"{path}: missing arrays {', '.join(missing)} (a press pack holds "
                             f"{', '.join(PACK_MEMBERS)})")
    return pack


def _slopes(pack: dict[str, np.ndarray], i: int, rim: float) -> tuple[np.ndarray, ...]:
    shape = pack["f0"].shape[:2]
    cx, cy = pack["touch_center"][i]
    r_px = GELSIGHT_BALL_RADIUS_MM / GELSIGHT_MM_PER_PX
    return ball_slopes(shape, (float(cy), float(cx)), float(pack["touch_radius"][i]), r_px, rim)


def evaluate_gelsight(
    path: str | Path, train: list[int] | None = None, bins: int = 24
) -> GelSightEvaluation:
    """Calibrate a LUT on the ``train`` presses (default: even indices) and test on the rest.

    Parameters
    ----------
    path
        ``dataPack_small.npz``.
    train
        Press indices for calibration.
    bins
        LUT nodes per colour axis.
    """
    pack = load_pack(path)
    images = pack["imgs"].astype(np.float32) / 255.0
    return evaluate_images(pack, images, pack["f0"].astype(np.float32) / 255.0, train, bins)


def split_presses(count: int, train: list[int] | None = None) -> tuple[list[int], list[int]]:
    """``(train, test)`` press indices: ``train`` (default: the even ones) and the rest."""
    train = list(range(0, count, 2)) if train is None else sorted(set(train))
    return train, [i for i in range(count) if i not in set(train)]


def evaluate_images(
    pack: dict[str, np.ndarray],
    images: np.ndarray,
    reference: np.ndarray,
    train: list[int] | None = None,
    bins: int = 24,
    lut: PhotometricLUT | None = None,
) -> GelSightEvaluation:
    """Photometric stereo on the pack's presses, given as ``images`` (``P × H × W × 3`` in
    [0, 1]: the pack's own or a translation of them) against ``reference``.

    A LUT is calibrated on the ``train`` presses with the annotated ball-cap slopes unless
    ``lut`` is given (then ``train`` only defines the held-out presses); it is tested on the
    others, inside 0.9 of their annotated circles.
    """
    train, test = split_presses(len(images), train)
    f0 = np.asarray(reference, np.float32)
    if lut is None:
        rng = np.random.default_rng(0)
        feats, gxs, gys, valids = [], [], [], []
        rr, cc = np.mgrid[0 : f0.shape[0], 0 : f0.shape[1]]
        for i in train:
            gx, gy, inside = _slopes(pack, i, 0.9)
            cx, cy = pack["touch_center"][i]
            far = np.hypot(rr - cy, cc - cx) > 1.6 * pack["touch_radius"][i]
            feats.append(images[i] - f0)
            gxs.append(gx)
            gys.append(gy)
            valids.append(inside | (far & (rng.random(far.shape) < 0.1)))
        lut = calibrate_lut(feats, gxs, gys, valids, bins=bins, meta={"source": "taxim-gelsight"})
    g_err, g_zero, d_err, peaks = [], [], [], []
    for i in test:
        gx, gy = lut.lookup(images[i] - f0)
        tx, ty, inside = _slopes(pack, i, 0.9)
        g_err.append(np.hypot(gx - tx, gy - ty)[inside])
        g_zero.append(np.hypot(tx, ty)[inside])
        fx, fy, _ = _slopes(pack, i, 1.0)
        d_true = integrate_gradients(fx, fy, GELSIGHT_MM_PER_PX)
        d_lut = integrate_gradients(gx, gy, GELSIGHT_MM_PER_PX)
        d_err.append((d_lut - d_true)[inside])
        peaks.append(float(d_true.max()))
    rms = lambda parts: float(np.sqrt(np.mean(np.concatenate(parts) ** 2)))  # noqa: E731
    return GelSightEvaluation(
        train=train,
        test=test,
        grad_rms=rms(g_err),
        grad_rms_zero=rms(g_zero),
        depth_rms_mm=rms(d_err),
        depth_peak_mm=float(np.mean(peaks)),
        lut=lut,
    )


def evaluate_gelsight_image_only(
    path: str | Path, train: list[int] | None = None, bins: int = 24,
    elastomer_sigma_mm: float = 0.25,
) -> tuple[float, float]:
    """The device-calibration path on real data: a LUT from the ``train`` presses using only
    the images and the ball radius (no annotations: press found in the image, smoothed-cap
    fit, one refinement; :func:`thintact_sdk.tactile.calibration.ball_press.calibrate_from_presses`),
    tested against the annotated-cap slopes of the other presses.

    Returns
    -------
    (grad_rms, grad_rms_zero)
        Slope RMS error inside 0.9 of the test circles, and that of "always flat".
    """
    from thintact_sdk.formats.profiles import SceneSpec, TactileConfig, load_profile
    from thintact_sdk.tactile.calibration.ball_press import BallPress, calibrate_from_presses
    from thintact_sdk.tactile.interpretation.colour_change import colour_change

    pack = load_pack(path)
    n = len(pack["imgs"])
    train = list(range(0, n, 2)) if train is None else list(train)
    test = [i for i in range(n) if i not in set(train)]
    rows, cols = pack["f0"].shape[:2]
    profile = load_profile("virtual-finger").model_copy(
        update={
            "name": "taxim-gelsight",
            "scene": SceneSpec(rows=rows, cols=cols, pixel_pitch_um=GELSIGHT_MM_PER_PX * 1000),
            "tactile": TactileConfig.model_validate(
                {"mm_per_px": GELSIGHT_MM_PER_PX, "elastomer_sigma_mm": elastomer_sigma_mm}),
        },
        deep=True,
    )
    f0 = pack["f0"].astype(np.float32) / 255.0
    presses = [BallPress(pack["imgs"][i].astype(np.float32) / 255.0) for i in train]
    lut = calibrate_from_presses(profile, f0, presses, GELSIGHT_BALL_RADIUS_MM, bins)
    err, zero = [], []
    for i in test:
        img = pack["imgs"][i].astype(np.float32) / 255.0
        gx, gy = lut.lookup(colour_change(img, f0, None, 1.0, 1.0))
        tx, ty, inside = _slopes(pack, i, 0.9)
        err.append(np.hypot(gx - tx, gy - ty)[inside])
        zero.append(np.hypot(tx, ty)[inside])
    return (float(np.sqrt(np.mean(np.concatenate(err) ** 2))),
            float(np.sqrt(np.mean(np.concatenate(zero) ** 2))))
