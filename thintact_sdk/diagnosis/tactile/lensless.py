"""Concealed tactile effects through the lensless path, with and without the correction
(a row of ``thintact bench tactile``).

The membrane's scenes get effects the SDK's tactile simulation leaves out (an illumination
field, a per-frame exposure drift, a response γ of the emitted light), are imaged by the
virtual camera and decoded. The diagnosis (:func:`.run.diagnose_tactile`) is run on
reconstructed presses of a calibration ball with the markers masked out, twice: on the plain
scenes (what the path itself does: the decoder's contrast loss and blur) and on the concealed
ones. The correction inverts the second model (:func:`.correction.correct_frames`) and applies
the first (background and response of the plain path), so the sensor's LUT, calibrated on the
plain simulation through the same path, reads what it was calibrated on.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from thintact_sdk.diagnosis.tactile.correction import correct_frames
from thintact_sdk.diagnosis.tactile.press_engine import TactileDiagnosisOptions, diagnose_tactile
from thintact_sdk.diagnosis.tactile.press_model import polynomial_basis
from thintact_sdk.tactile.calibration.evaluation import depth_rms
from thintact_sdk.tactile.interpretation.markers import detect_markers
from thintact_sdk.tactile.learning.domains import RealPresses
from thintact_sdk.tactile.simulation.indenters import Sphere
from thintact_sdk.tactile.simulation.membrane import TactileSimulator

CONCEALED_FIELD = np.array([[1.0, 0.15, -0.10], [1.0, 0.10, -0.12], [1.0, 0.18, -0.06]])
"""Per channel coefficients of the concealed illumination field on (1, y, x) (the order of
:func:`.model.polynomial_basis`), x and y in [−1, 1] over the image."""
CONCEALED_GAMMA = 0.8
CONCEALED_EXPOSURE_SD = 0.03


@dataclass
class ConcealedRow:
    """Depth RMS (mm, mean over presses) of the 4 mm sphere with concealed effects."""

    depth_mm: float
    plain_mm: float
    concealed_mm: float
    corrected_mm: float
    presses: int


def conceal(scene: np.ndarray, exposure: np.ndarray) -> np.ndarray:
    """The scene with the concealed field, exposure and γ applied (``N × M × 3``)."""
    h, w = scene.shape[:2]
    basis = polynomial_basis(h, w, 1)
    field = np.einsum("ck,khw->hwc", CONCEALED_FIELD, basis)
    return np.clip((np.clip(scene, 0, 1) * field * exposure) ** CONCEALED_GAMMA, 0, 1).astype(np.float32)


def evaluate_concealed(sensor: object, show: Callable[[np.ndarray | None], None],
                       presses: int = 3, calibration_presses: int = 8, seed: int = 0,
                       depths_mm: tuple[float, ...] = (0.5, 1.0)) -> tuple[list[ConcealedRow], dict]:
    """The concealed-effect rows (see module docstring); also returns the diagnosis report."""
    profile = sensor.profile  # type: ignore[attr-defined]
    interp = sensor.interpreter  # type: ignore[attr-defined]
    read_image = sensor.read_image  # type: ignore[attr-defined]
    sim = TactileSimulator.for_profile(profile)
    p = sim.params
    rng = np.random.default_rng(seed)
    ones = np.ones(3)

    def image(scene: np.ndarray, frames: int = 1) -> np.ndarray:
        show(scene)
        return np.mean([read_image() for _ in range(frames)], axis=0)

    plain_ref = image(sim.flat().scene, 4)
    ref = image(conceal(sim.flat().scene, ones), 4)
    ball = 1.5
    half = (p.cols / 2 * p.mm_per_px - 2 * ball, p.rows / 2 * p.mm_per_px - 2 * ball)
    calib = []
    for _ in range(calibration_presses):
        centre = (float(rng.uniform(-half[0], half[0])), float(rng.uniform(-half[1], half[1])))
        calib.append(sim.press(Sphere(ball), float(rng.uniform(0.4, 1.0)), centre).scene)
    effects = ("illumination_field", "exposure_drift", "camera_gamma", "elastomer_blur")

    def diagnose(scenes: list[np.ndarray], reference: np.ndarray) -> Any:
        imgs = [image(sc) for sc in scenes]
        masks = np.stack([detect_markers(im, p).mask for im in imgs])
        real = RealPresses(np.stack(imgs).astype(np.float32), reference.astype(np.float32),
                           "lensless path")
        return diagnose_tactile(real, ball, p.mm_per_px, exclude=masks,
                                options=TactileDiagnosisOptions(effects=effects))

    # the path's own response (decoder contrast and blur) is diagnosed on the plain scenes and
    # kept; only what the concealed scenes add is inverted
    path = diagnose(calib, plain_ref).final
    diag = diagnose([conceal(sc, 1 + CONCEALED_EXPOSURE_SD * rng.standard_normal(3))
                     for sc in calib], ref)
    model = diag.final
    h, w = ref.shape[:2]
    path_bg = path.background(polynomial_basis(h, w, path.field_order), np.zeros((h, w, 3)))

    def correct(img: np.ndarray) -> np.ndarray:
        shading = correct_frames(model, img[None], ref, ball, p.mm_per_px)[0]
        return path.respond(path_bg * shading).astype(np.float32)

    corr_ref = correct(ref)
    rows = []
    for depth in depths_mm:
        e_plain, e_conc, e_corr = [], [], []
        for _ in range(presses):
            centre = (float(rng.uniform(-half[0], half[0])), float(rng.uniform(-half[1], half[1])))
            truth = sim.press(Sphere(2.0), depth, centre, float(rng.uniform(0, 180)))
            thr = p.contact_threshold_mm
            interp.set_reference(plain_ref.astype(np.float32))
            e_plain.append(depth_rms(interp.depth_from_image(image(truth.scene)), truth.depth_mm, thr))
            img = image(conceal(truth.scene, 1 + CONCEALED_EXPOSURE_SD * rng.standard_normal(3)))
            interp.set_reference(ref.astype(np.float32))
            e_conc.append(depth_rms(interp.depth_from_image(img), truth.depth_mm, thr))
            interp.set_reference(corr_ref)
            e_corr.append(depth_rms(interp.depth_from_image(correct(img)), truth.depth_mm, thr))
        rows.append(ConcealedRow(depth, float(np.nanmean(e_plain)), float(np.nanmean(e_conc)),
                                 float(np.nanmean(e_corr)), presses))
    show(None)
    interp.set_reference(plain_ref.astype(np.float32))
    return rows, diag.report
