"""Tactile (LUT) calibration of a whole device: ball presses through the real image path.

Three sources, one result (a :class:`~thintact_sdk.tactile.interpretation.photometric.PhotometricLUT`
calibrated on *reconstructed* images, so it absorbs what the lensless reconstruction does
to colours):

* virtual sensor: the tactile simulator presses a ball at random places and depths, the
  scenes are injected into the virtual camera's scene slot, and the simulator's slopes
  are the ground truth;
* recording (``thintact-recording/1``): the frame labelled ``reference`` (else the first)
  is the no-contact frame, every other frame is a ball press; slopes from the ball model
  (contact circle found in the image, known ball radius);
* live camera: the user is prompted to keep the membrane free, then to press the ball
  several times; slopes from the ball model.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.device.virtual_bench import get_scene_slot
from thintact_sdk.errors import CalibrationError
from thintact_sdk.frames import Measurement
from thintact_sdk.tactile.calibration.ball_press import (
    CALIBRATION_BALL_RADIUS_MM,
    BallPress,
    calibrate_from_presses,
    press_contact_radius_mm,
    random_ball_presses,
)
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT
from thintact_sdk.tactile.simulation.membrane import TactileSimulator

Progress = Callable[[int, int], None]


def _mean_image(read: Callable[[], np.ndarray], frames: int) -> np.ndarray:
    acc = read().astype(np.float64)
    for _ in range(frames - 1):
        acc += read()
    return (acc / frames).astype(np.float32)


def scene_slot(sensor: Any) -> Any:
    """The virtual bench's scene slot that ``sensor``'s simulated camera renders
    (:mod:`thintact_sdk.device.virtual_bench`; the key is the camera's ``slot`` setting or the
    profile name)."""
    key = sensor.camera_settings.get("slot")
    if key is None and sensor.profile.camera is not None:
        key = sensor.profile.camera.settings.get("slot")
    return get_scene_slot(key or sensor.profile.name)


def calibrate_virtual(
    sensor: Any,
    presses: int = 12,
    ball_radius_mm: float = CALIBRATION_BALL_RADIUS_MM,
    frames_per_image: int = 1,
    bins: int = 32,
    seed: int = 0,
    progress: Progress | None = None,
    reference_frames: int = 4,
) -> PhotometricLUT:
    """Calibrate through a virtual sensor (opened :class:`~thintact_sdk.device.sensor.Sensor`).

    Parameters
    ----------
    sensor
        An opened sensor whose camera is the virtual one.
    presses
        Number of simulated ball presses.
    ball_radius_mm
        Calibration ball radius (paper: 3 mm ball → 1.5 mm).
    frames_per_image
        Frames averaged per press image. Keep 1: the LUT then learns colours with the noise
        of the single frames it will see (averaged calibration frames made the depth error
        of single frames 3-6× larger on the virtual finger).
    reference_frames
        Frames averaged for the no-contact reference (as the Sensor does).
    bins, seed
        LUT nodes per colour axis; seed of the press positions.
    """
    slot = scene_slot(sensor)
    sim = TactileSimulator.for_profile(sensor.profile)
    data = random_ball_presses(sensor.profile, presses, ball_radius_mm, seed=seed)
    try:
        slot.set(sim.flat().scene)
        reference = _mean_image(sensor.read_image, reference_frames)
        items = []
        for i, (scene, press) in enumerate(data):
            slot.set(scene.scene)
            img = _mean_image(sensor.read_image, frames_per_image)
            items.append(BallPress(img, scene.grad_x, scene.grad_y,
                                   press_contact_radius_mm(press)))
            if progress is not None:
                progress(i + 1, len(data))
    finally:
        slot.set(None)
    return calibrate_from_presses(
        sensor.profile, reference, items, ball_radius_mm, bins,
        meta={"source": "virtual", "frames_per_image": frames_per_image,
              "reference_frames": reference_frames},
    )


def calibrate_recording(
    sensor: Any,
    recording_dir: str | Path,
    ball_radius_mm: float = CALIBRATION_BALL_RADIUS_MM,
    bins: int = 32,
    progress: Progress | None = None,
    model: str = "lut",
    stage: Callable[[str], None] | None = None,
    ball_model: str = "auto",
) -> PhotometricLUT:
    """Calibrate from a recording of ball presses (reference frame + press frames);
    ``model``, ``stage`` and ``ball_model`` as in
    :func:`~thintact_sdk.tactile.calibration.ball_press.calibrate_from_presses`."""
    from thintact_sdk.formats.recording import Recording

    rec = Recording(recording_dir, sensor.profile)
    if len(rec) < 2:
        raise CalibrationError(
            f"recording {recording_dir} has {len(rec)} frame(s); it needs a no-contact frame "
            "and at least one ball press"
        )
    labels = [f.label for f in rec.frames]
    ref_i = labels.index("reference") if "reference" in labels else 0
    black = float(sensor.profile.noise.black_level_dn)

    def image(i: int) -> np.ndarray:
        m = Measurement(rec.measurement(i).astype(np.float32), black)
        return np.asarray(sensor.reconstruct(m), np.float32)

    reference = image(ref_i)
    items = []
    others = [i for i in range(len(rec)) if i != ref_i]
    for k, i in enumerate(others):
        items.append(BallPress(image(i)))
        if progress is not None:
            progress(k + 1, len(others))
    return calibrate_from_presses(
        sensor.profile, reference, items, ball_radius_mm, bins,
        meta={"source": "recording", "recording": str(recording_dir)}, model=model, stage=stage,
        ball_model=ball_model,
    )


def calibrate_live(
    sensor: Any,
    presses: int = 8,
    ball_radius_mm: float = CALIBRATION_BALL_RADIUS_MM,
    frames_per_image: int = 1,
    bins: int = 32,
    prompt: Callable[[str], object] = input,
    progress: Progress | None = None,
    reference_frames: int = 4,
    model: str = "lut",
    stage: Callable[[str], None] | None = None,
    ball_model: str = "auto",
) -> PhotometricLUT:
    """Calibrate a live sensor: the user keeps the membrane free, then presses the ball
    (press images are single frames, like the frames the LUT will see); ``model``,
    ``stage`` and ``ball_model`` as in
    :func:`~thintact_sdk.tactile.calibration.ball_press.calibrate_from_presses`."""
    prompt(
        f"Keep the membrane of {sensor.profile.name!r} free of contact and press Enter: "
    )
    reference = _mean_image(sensor.read_image, reference_frames)
    items = []
    for i in range(presses):
        prompt(
            f"Press the {2 * ball_radius_mm:g} mm ball about 0.5-1 mm into the membrane, at a "
            f"new place ({i + 1}/{presses}), hold it and press Enter: "
        )
        items.append(BallPress(_mean_image(sensor.read_image, frames_per_image)))
        if progress is not None:
            progress(i + 1, presses)
    return calibrate_from_presses(
        sensor.profile, reference, items, ball_radius_mm, bins, meta={"source": "live"},
        model=model, stage=stage, ball_model=ball_model,
    )
