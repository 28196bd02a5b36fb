"""Reconstruct every frame of a recording with a calibration bundle (``thintact reconstruct``).

Each frame's measurement (raw DN) minus the dark level (the recording's dark frames, i.e.
all-zero scenes, when it has any, else the profile's black level), normalised to the
bundle's exposure when both are known, goes through the decoder; the estimate is written as
``out/<measurement file stem>.npy`` (``N × M × C`` float32, display units).

Every frame is checked before anything is written (a NaN, Inf or negative measurement is
refused naming the frame), two frames whose estimates would land in the same file are
refused, and an estimate that is not finite is an error naming the frame, never a silent
all-NaN file.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thintact_sdk.errors import CalibrationError, RecordingError
from thintact_sdk.formats.recording import Recording

__all__ = ["ReconstructionRun", "check_unique_outputs", "reconstruct_recording"]


@dataclass(frozen=True)
class ReconstructionRun:
    """What :func:`reconstruct_recording` did: the estimates written (paths, in frame order),
    the decoder's name, the dark level's source, and a warning when the bundle was made for
    other physics than the recording's profile (``None`` otherwise)."""

    written: list[Path]
    decoder: str
    dark_source: str
    profile_warning: str | None


def check_unique_outputs(rec: Recording) -> None:
    """Refuse frames whose estimates would land in the same ``<stem>.npy`` file."""
    seen: dict[str, int] = {}
    for i, fr in enumerate(rec.frames):
        stem = Path(fr.measurement).stem
        if stem in seen:
            raise RecordingError(
                f"recording {rec.root}: frames {seen[stem]} and {i} would both be written as "
                f"{stem}.npy (their measurement files share a name); one would overwrite the other"
            )
        seen[stem] = i


def reconstruct_recording(
    recording: str | Path | Recording,
    calibration: str | Path,
    out: str | Path,
    *,
    decoder: str | None = None,
    tau: float | None = None,
    dark_frames: bool = True,
    on_start: Callable[[ReconstructionRun], None] | None = None,
    advance: Callable[[], None] | None = None,
) -> ReconstructionRun:
    """Decode every frame of ``recording`` with the bundle ``calibration`` into ``out``.

    Parameters
    ----------
    recording
        A ``thintact-recording/1`` directory (or an opened :class:`Recording`).
    calibration
        Calibration bundle directory.
    out
        Output directory (created; the caller decides whether it may exist).
    decoder
        Decoder name (default: the bundle's ``decoder``, else the calibration's default).
    tau
        Tikhonov τ (DN², > 0) overriding the bundle's.
    dark_frames
        Subtract the recording's dark frames (all-zero scenes) when it has any; ``False``:
        always the profile's black level.
    on_start
        Called once everything is checked, before the first frame is decoded (with the
        run's decoder, dark source and profile warning; ``written`` still empty).
    advance
        Called after each frame is written (a progress bar's step).
    """
    from thintact_sdk.calibration.collect import dark_level, frame_exposure_us
    from thintact_sdk.calibration.validation import make_decoder
    from thintact_sdk.reconstruction.bundle import CalibrationBundle

    rec = recording if isinstance(recording, Recording) else Recording(recording)
    check_unique_outputs(rec)
    rec.check_frames()
    profile = rec.profile
    bundle = CalibrationBundle.load(calibration)
    bundle.check_shapes(profile)
    warning = None if bundle.matches_profile(profile) else (
        f"the calibration was made for profile {bundle.meta.get('profile')!r} with other physics "
        "fields than this recording's profile")
    settings = {} if tau is None else {"tau": tau}
    name = decoder or bundle.meta.get("decoder") or None
    dec = make_decoder(profile, bundle, None if name is None else str(name), **settings)
    ref_exposure = bundle.meta.get("exposure_us")
    dark, dark_source = dark_level(rec, use_dark_frames=dark_frames)
    dark32 = dark.astype(np.float32)
    run = ReconstructionRun([], str(getattr(dec, "name", name)), dark_source, warning)
    if on_start is not None:
        on_start(run)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for i, fr in enumerate(rec.frames):
        meas = np.asarray(rec.measurement(i), np.float32)
        if meas.ndim == 2:
            meas = meas[..., None]
        signal = meas - dark32[..., : meas.shape[2]]
        exposure = frame_exposure_us(rec, i)
        if isinstance(ref_exposure, int | float) and exposure is not None:
            signal *= np.float32(ref_exposure / exposure)
        estimate = np.asarray(dec.decode(signal), np.float32)
        if not np.isfinite(estimate).all():
            raise CalibrationError(
                f"frame {i} ({fr.label or fr.measurement}): the decoder returned NaN/Inf "
                f"values (measurement {float(meas.min()):.4g}..{float(meas.max()):.4g} DN, "
                f"calibration {calibration}); nothing was written for it"
            )
        path = out / f"{Path(fr.measurement).stem}.npy"
        np.save(path, estimate)
        run.written.append(path)
        if advance is not None:
            advance()
    return run
