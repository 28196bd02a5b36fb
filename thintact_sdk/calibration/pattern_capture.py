"""Averaged captures: K frames per pattern, saturation checks, exposure from the white frame."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from thintact_sdk.device.cameras import to_measurement
from thintact_sdk.errors import CalibrationError, InvalidValueError, UnsupportedFeatureError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.interfaces import Camera, Display


@dataclass
class AveragedFrame:
    """The mean of K binned frames.

    Attributes
    ----------
    data
        ``R × S × 3`` float32 DN, black level not removed (as recordings store it).
    frames
        K.
    saturated_fraction
        Largest fraction of binned pixels at saturation in any of the K frames.
    exposure_us
        Exposure reported by the frames (None if the camera does not say).
    frame_ids
        First and last camera frame id averaged.
    """

    data: np.ndarray
    frames: int
    saturated_fraction: float
    exposure_us: float | None
    frame_ids: tuple[int, int]


def capture_average(
    camera: Camera, profile: Profile, frames: int, flush: int = 1, timeout_s: float = 5.0
) -> AveragedFrame:
    """Average ``frames`` frames after discarding ``flush`` (possibly taken before the pattern changed).

    Parameters
    ----------
    camera
        An opened camera.
    profile
        Binning and saturation level.
    frames
        K ≥ 1 frames averaged (paper: 100).
    flush
        Frames read and dropped first.
    timeout_s
        Per-frame read timeout (s).
    """
    if frames < 1:
        raise InvalidValueError("frames must be >= 1")
    for _ in range(flush):
        camera.read(timeout_s=timeout_s)
    acc = np.zeros((profile.sensor.rows, profile.sensor.cols, len(profile.sensor.channels)), np.float64)
    sat_level = profile.noise.saturation_dn - 1.0
    sat = 0.0
    exposure = None
    first = last = -1
    for k in range(frames):
        raw = camera.read(timeout_s=timeout_s)
        m = to_measurement(raw, profile)
        acc += m.data
        sat = max(sat, float(np.mean(m.data >= sat_level)))
        exposure = m.exposure_us if m.exposure_us is not None else exposure
        if k == 0:
            first = m.frame_id
        last = m.frame_id
    return AveragedFrame((acc / frames).astype(np.float32), frames, sat, exposure, (first, last))


def show_and_capture(
    display: Display,
    camera: Camera,
    profile: Profile,
    scene: np.ndarray,
    frames: int,
    flush: int = 1,
) -> AveragedFrame:
    """Show ``scene``, wait ``display.settle_s``, then :func:`capture_average`."""
    display.show(scene)
    settle = profile.display.settle_s if profile.display is not None else 0.0
    if settle > 0:
        time.sleep(settle)
    return capture_average(camera, profile, frames, flush)


def white_peak_dn(frame: AveragedFrame, profile: Profile) -> float:
    """99.9th percentile of the white frame above black (DN): the exposure's yardstick."""
    return float(np.percentile(frame.data - profile.noise.black_level_dn, 99.9))


def set_exposure_from_white(
    display: Display,
    camera: Camera,
    profile: Profile,
    target_fraction: float = 0.7,
    frames: int = 2,
    max_rounds: int = 6,
) -> float | None:
    """Set the exposure so the white frame peaks at ``target_fraction`` of full scale, unsaturated.

    Full scale is ``saturation_dn − black_level_dn``. A saturated white frame halves the
    exposure; otherwise it is scaled by ``target / peak`` (clamped to the camera's range)
    until within 10 % of the target.

    Returns
    -------
    float or None
        The exposure set (us), or None when the camera has no exposure control (then the
        white frame must not saturate as it is).

    Raises
    ------
    CalibrationError
        When the white frame saturates and the exposure cannot be lowered, or there is no
        signal at all.
    """
    n, m = profile.scene.rows, profile.scene.cols
    white = np.ones((n, m, 3), np.float32)
    full = profile.noise.saturation_dn - profile.noise.black_level_dn
    target = target_fraction * full
    caps = camera.capabilities()
    lo, hi = (caps.exposure_range_us.min, caps.exposure_range_us.max) if caps.exposure_range_us else (1.0, 1e7)
    frame = show_and_capture(display, camera, profile, white, frames)
    exposure = frame.exposure_us
    for _ in range(max_rounds):
        peak = white_peak_dn(frame, profile)
        ok = frame.saturated_fraction == 0.0 and abs(peak - target) <= 0.1 * target
        if ok:
            return exposure
        if exposure is None:
            break
        if frame.saturated_fraction > 0:
            new = exposure / 2
        elif peak <= 0:
            raise CalibrationError(
                "the white frame shows no signal above black: is the display on and the sensor "
                "facing it?"
            )
        else:
            new = exposure * target / peak
        new = float(np.clip(new, lo, hi))
        if new == exposure:
            break
        try:
            camera.set_exposure_us(new)
        except UnsupportedFeatureError:
            exposure = None
            break
        frame = show_and_capture(display, camera, profile, white, frames)
        exposure = frame.exposure_us if frame.exposure_us is not None else new
    if frame.saturated_fraction > 0:
        raise CalibrationError(
            f"the white frame saturates ({100 * frame.saturated_fraction:.2f} % of pixels) and the "
            "exposure cannot be lowered further: dim the display or the camera gain"
        )
    return exposure
