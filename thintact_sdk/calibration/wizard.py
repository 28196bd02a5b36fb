"""The calibration wizard: drive an LCD through the pattern sequence, record, resume, solve.

Every averaged frame is written atomically into ``<bundle>/capture/`` (a
``thintact-recording/1`` directory) the moment it is captured. A killed run resumes from
that recording: patterns already recorded are skipped (by label), the exposure is restored
from the recorded white frame, and nothing captured is lost or recorded twice.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.calibration.capture_worker import CaptureWorker
from thintact_sdk.calibration.pattern_capture import set_exposure_from_white, show_and_capture
from thintact_sdk.calibration.pipeline import (
    CalibrationOptions,
    CalibrationOutcome,
    calibrate_recording,
)
from thintact_sdk.calibration.plan import REGISTRATION_CORNERS, Step, build_plan
from thintact_sdk.calibration.registration import RegistrationResult, check_registration
from thintact_sdk.errors import CalibrationError, UnsupportedFeatureError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.formats.recording import Recording, RecordingWriter, remove_partial_writes
from thintact_sdk.interfaces import Camera, Display
from thintact_sdk.reconstruction.bundle import META_FILE, timestamp_name
from thintact_sdk.reconstruction.t2s import SystemMatrices

CAPTURE_DIR = "capture"
StepProgress = Callable[[int, int, str], None]
"""``progress(done, total, label)`` after each pattern (done counts resumed ones too)."""


@dataclass
class WizardSettings:
    """How the wizard captures.

    Attributes
    ----------
    frames
        K frames averaged per pattern (paper: 100).
    flush
        Frames dropped after each pattern change (after ``display.settle_s``).
    exposure_target
        White-frame peak as a fraction of full scale.
    check_registration
        Stop before the slit scan when the registration check fails.
    validation
        Validation scene specs (``name`` or ``name:index``).
    """

    frames: int = 8
    flush: int = 1
    exposure_target: float = 0.7
    check_registration: bool = True
    validation: tuple[str, ...] | None = None


def bundle_root(profile: Profile, base: Path | None = None) -> Path:
    """``calibrations/<device>/`` (relative to ``base``, default the working directory)."""
    return (base or Path.cwd()) / "calibrations" / profile.name


def find_unfinished(device_dir: Path) -> Path | None:
    """The newest bundle directory with a capture but no ``calibration.json`` (a run to resume)."""
    if not device_dir.is_dir():
        return None
    candidates = sorted(
        d for d in device_dir.iterdir()
        if d.is_dir() and (d / CAPTURE_DIR / "manifest.json").is_file() and not (d / META_FILE).is_file()
    )
    return candidates[-1] if candidates else None


def new_bundle_dir(profile: Profile, base: Path | None = None) -> Path:
    """A fresh ``calibrations/<device>/<YYYYmmddTHHMMSS>/`` path (not created)."""
    return bundle_root(profile, base) / timestamp_name()


def _check_same_profile(capture: Path, profile: Profile) -> None:
    try:
        rec = Recording(capture, allow_empty=True)
    except Exception as err:  # noqa: BLE001 - any unreadable capture is reported the same way
        raise CalibrationError(f"cannot resume from {capture}: {err}") from None
    if rec.profile.content_hash() != profile.content_hash():
        raise CalibrationError(
            f"the capture in {capture} was made with a different profile (its physics fields "
            "differ); start a new calibration with --restart or another --out"
        )


def _restore_exposure(camera: Camera, writer: RecordingWriter) -> float | None:
    for fr in writer.frames:
        if fr.label == "white" and isinstance(fr.extra.get("exposure_us"), int | float):
            exposure = float(fr.extra["exposure_us"])
            try:
                camera.set_exposure_us(exposure)
            except UnsupportedFeatureError:
                return None
            return exposure
    return None


def wizard_plan(profile: Profile, settings: WizardSettings) -> list[Step]:
    """The patterns the wizard captures for ``profile`` with ``settings`` (its validation
    scenes, else the plan's default ones)."""
    return build_plan(profile, settings.validation) if settings.validation is not None else build_plan(profile)


def capture_session(
    profile: Profile,
    capture_dir: Path,
    camera: Camera,
    display: Display,
    settings: WizardSettings,
    progress: StepProgress | None = None,
    status: Callable[[str], None] | None = None,
    on_written: Callable[[], None] | None = None,
) -> RegistrationResult:
    """Record every pattern of the plan into ``capture_dir`` (resuming what is there).

    ``camera`` and ``display`` must be open. Returns the registration check (raises
    :class:`CalibrationError` when it fails and ``settings.check_registration``).
    ``on_written()`` is called after each pattern is written (or found, resuming): the
    pipelined calibration's :class:`~thintact_sdk.calibration.capture_worker.CaptureWorker`.
    """
    plan = wizard_plan(profile, settings)
    writer = RecordingWriter(capture_dir, profile)
    total = len(plan)
    exposure = _restore_exposure(camera, writer) if writer.has_label("white") else None
    if not writer.has_label("white"):
        if status:
            status("setting the exposure from the white frame")
        exposure = set_exposure_from_white(display, camera, profile, settings.exposure_target)
    registration: RegistrationResult | None = None
    done = 0
    for step in plan:
        if step.kind == "hslit" and registration is None:
            registration = _registration(capture_dir, profile)
            if status:
                status("registration " + ("passed" if registration.passed else "FAILED: " + "; ".join(registration.problems)))
            if settings.check_registration and not registration.passed:
                raise CalibrationError("registration check failed: " + "; ".join(registration.problems))
        if not writer.has_label(step.label):
            _capture_step(step, writer, camera, display, profile, settings, exposure)
        if on_written is not None:
            on_written()
        done += 1
        if progress:
            progress(done, total, step.label)
    if registration is None:
        registration = _registration(capture_dir, profile)
    return registration


def _capture_step(
    step: Step,
    writer: RecordingWriter,
    camera: Camera,
    display: Display,
    profile: Profile,
    settings: WizardSettings,
    exposure: float | None,
) -> None:
    scene = step.make()
    frame = show_and_capture(display, camera, profile, scene, settings.frames, settings.flush)
    extra: dict[str, Any] = {
        "kind": step.kind,
        "frames": frame.frames,
        "saturated_fraction": frame.saturated_fraction,
        "frame_ids": list(frame.frame_ids),
    }
    exp = frame.exposure_us if frame.exposure_us is not None else exposure
    if exp is not None:
        extra["exposure_us"] = float(exp)
    writer.add(frame.data, scene, label=step.label, **extra)


def _registration(capture_dir: Path, profile: Profile) -> RegistrationResult:
    rec = Recording(capture_dir, profile=profile)
    by_label = {f.label: i for i, f in enumerate(rec.frames)}
    dark = np.asarray(rec.measurement(by_label["dark"]), np.float64) if "dark" in by_label else profile.noise.black_level_dn
    signals = {}
    for c in REGISTRATION_CORNERS:
        i = by_label.get(f"reg_{c}")
        if i is None:
            raise CalibrationError(f"registration frame reg_{c} missing from {capture_dir}")
        signals[c] = np.asarray(rec.measurement(i), np.float64) - dark
    return check_registration(signals, profile)


def run_wizard(
    profile: Profile,
    bundle_dir: Path,
    camera: Camera,
    display: Display,
    settings: WizardSettings | None = None,
    options: CalibrationOptions | None = None,
    progress: StepProgress | None = None,
    status: Callable[[str], None] | None = None,
    reference: SystemMatrices | None = None,
    reference_exposure_us: float | None = None,
    pipelined: bool = True,
) -> CalibrationOutcome:
    """Capture (or resume) into ``bundle_dir/capture`` and write the bundle in ``bundle_dir``.

    ``camera`` and ``display`` are opened and closed here. ``pipelined``: compress and solve
    the slits, and simulate the prediction's design, while the capture runs
    (:mod:`~thintact_sdk.calibration.capture_worker`); the calibration records the seconds
    from the last pattern to the bundle (``metrics.after_last_pattern_s``).
    """
    ws = settings or WizardSettings()
    capture_dir = bundle_dir / CAPTURE_DIR
    if (capture_dir / "manifest.json").is_file():
        _check_same_profile(capture_dir, profile)
        remove_partial_writes(capture_dir)
    bundle_dir.mkdir(parents=True, exist_ok=True)
    (bundle_dir / "wizard.json").write_text(
        json.dumps({"frames": ws.frames, "flush": ws.flush, "exposure_target": ws.exposure_target}) + "\n",
        encoding="utf-8",
    )
    opts = options or CalibrationOptions()
    plan = wizard_plan(profile, ws)
    worker = CaptureWorker(profile, capture_dir, opts,
                           opts.frames_averaged if opts.frames_averaged is not None else ws.frames,
                           sum(s.kind in ("hslit", "vslit") for s in plan),
                           [(s.label, s.make()) for s in plan if s.kind == "validation"]) if pipelined else None
    with camera, display:
        registration = capture_session(profile, capture_dir, camera, display, ws, progress, status,
                                       None if worker is None else worker.frame_written)
    captured = time.monotonic()
    prepared = None
    if worker is not None:
        if status:
            status("finishing the work done during the capture")
        prepared = worker.finish()
    rec = Recording(capture_dir, profile=profile)
    return calibrate_recording(
        rec, bundle_dir, opts, source="wizard", status=status, registration=registration,
        reference=reference, reference_exposure_us=reference_exposure_us, prepared=prepared,
        capture_ended=captured,
    )
