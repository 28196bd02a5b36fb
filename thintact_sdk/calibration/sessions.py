"""A calibration run as ``thintact calibrate`` makes it: from a recording, or with the wizard.

:func:`calibrate_from_recording` reads and checks a recording (every frame named before any
work) and solves it (:func:`thintact_sdk.calibration.pipeline.calibrate_recording`);
:func:`calibrate_with_wizard` builds the profile's camera and display through the registry,
chooses or resumes the bundle directory and runs the LCD wizard
(:func:`thintact_sdk.calibration.wizard.run_wizard`). Both can compare the result with the
simulator's two-term fit (:func:`simulator_reference`, virtual devices). The command only
parses, shows progress and prints the outcome.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from thintact_sdk.calibration.collect import Progress
from thintact_sdk.calibration.outcome import CalibrationOutcome
from thintact_sdk.calibration.pipeline import CalibrationOptions, calibrate_recording
from thintact_sdk.device.virtual_bench import REFERENCE_EXPOSURE_US
from thintact_sdk.errors import ProfileError, ThinTactError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.formats.recording import Recording
from thintact_sdk.reconstruction.t2s import SystemMatrices

__all__ = [
    "REFERENCE_EXPOSURE_US",
    "calibrate_from_recording",
    "calibrate_with_wizard",
    "simulator_reference",
    "wizard_bundle_dir",
]

VIRTUAL_FRAMES_PER_PATTERN = 8
"""Frames averaged per pattern by default on a camera that renders the simulator's world."""
FRAMES_PER_PATTERN = 100
"""Frames averaged per pattern by default on a real camera."""


def simulator_reference(profile: Profile, camera_settings: Mapping[str, Any] | None = None) -> SystemMatrices:
    """The simulator's two-term fit of ``profile``'s system matrices, in DN at the virtual
    camera's signal scale for the profile's camera settings updated by ``camera_settings``
    (expressed at :data:`REFERENCE_EXPOSURE_US`): what ``--compare-reference`` compares with."""
    from thintact_sdk.device.virtual_bench import signal_scale_dn
    from thintact_sdk.simulation.simulator import Simulator

    settings = dict(profile.camera.settings) if profile.camera is not None else {}
    settings.update(camera_settings or {})
    return SystemMatrices.two_term_fit(Simulator(profile), scale_dn=signal_scale_dn(profile, settings))


def calibrate_from_recording(
    recording: str | Path,
    out: str | Path,
    options: CalibrationOptions | None = None,
    *,
    compare_reference: bool = False,
    progress: Progress | None = None,
    status: Callable[[str], None] | None = None,
) -> CalibrationOutcome:
    """Calibrate from the recording ``recording`` into the bundle directory ``out``, as
    ``thintact calibrate --from-recording`` does. Every frame is checked first
    (:meth:`Recording.check_frames`); ``progress(done, total, label)`` follows the slit
    frames, ``status`` receives the stage lines.

    Raises
    ------
    ThinTactError
        An unreadable recording or a bad frame (named), or a failed solve.
    """
    rec = Recording(recording)
    rec.check_frames()  # a NaN, negative or unreadable frame is named before any work
    return calibrate_recording(
        rec, Path(out), options or CalibrationOptions(), source="recording", progress=progress, status=status,
        reference=simulator_reference(rec.profile) if compare_reference else None,
        reference_exposure_us=REFERENCE_EXPOSURE_US,
    )


def wizard_bundle_dir(profile: Profile, out: Path | None, *, restart: bool = False,
                      base: Path | None = None) -> tuple[Path, bool]:
    """``(bundle directory, resumed)`` for the wizard: ``out`` when given, else the newest
    unfinished run under ``base/calibrations/<device>/`` (unless ``restart``; ``base``
    defaults to the working directory), else a new timestamped directory there.

    Raises
    ------
    ProfileError
        ``restart`` with a directory that already holds a capture.
    """
    from thintact_sdk.calibration.wizard import CAPTURE_DIR, find_unfinished, new_bundle_dir

    resumed = False
    if out is not None:
        bundle_dir = out
    else:
        unfinished = None if restart else find_unfinished((base or Path.cwd()) / "calibrations" / profile.name)
        bundle_dir = unfinished or new_bundle_dir(profile, base)
        resumed = unfinished is not None
    if restart and (bundle_dir / CAPTURE_DIR).exists():
        raise ProfileError(f"--restart: {bundle_dir} already holds a capture; choose another --out")
    return bundle_dir, resumed


def calibrate_with_wizard(
    profile: Profile,
    bundle_dir: Path,
    options: CalibrationOptions | None = None,
    *,
    frames: int | None = None,
    flush: int = 1,
    check_registration: bool = True,
    camera_settings: Mapping[str, Any] | None = None,
    compare_reference: bool = False,
    progress: Progress | None = None,
    status: Callable[[str], None] | None = None,
) -> CalibrationOutcome:
    """Run the LCD calibration wizard for ``profile`` into ``bundle_dir`` (an unfinished
    capture there is resumed; :func:`wizard_bundle_dir` chooses one), as ``thintact calibrate
    --profile`` does. ``frames`` averaged per pattern (None: :data:`VIRTUAL_FRAMES_PER_PATTERN`
    on a simulated camera, else :data:`FRAMES_PER_PATTERN`), ``flush`` frames dropped after
    each pattern change; ``camera_settings`` override the profile's. ``progress(done, total,
    label)`` follows the patterns, ``status`` receives the wizard's lines.

    Raises
    ------
    ProfileError
        The profile has no camera or no display section.
    ThinTactError
        A failed capture or solve; when frames were captured, the message says they are kept
        in ``bundle_dir/capture`` and that running again resumes.
    """
    from thintact_sdk.calibration.wizard import CAPTURE_DIR, WizardSettings, run_wizard
    from thintact_sdk.device.cameras import camera_is_simulated, create_camera
    from thintact_sdk.device.registry import get_registry

    if profile.camera is None:
        raise ProfileError(f"profile {profile.name!r} has no camera section: the wizard needs a camera")
    if profile.display is None:
        raise ProfileError(
            f"profile {profile.name!r} has no display section: add display.plugin (pygame or "
            "virtual), display_index, origin_px and pixel_pitch_um"
        )
    settings = dict(camera_settings or {})
    if frames is None:
        frames = VIRTUAL_FRAMES_PER_PATTERN if camera_is_simulated(profile) else FRAMES_PER_PATTERN
    camera = create_camera(profile, settings=settings)
    display = get_registry().create("display", profile.display.plugin, profile, dict(profile.display.settings))
    reference = simulator_reference(profile, settings) if compare_reference else None
    try:
        return run_wizard(
            profile, bundle_dir, camera, display,
            WizardSettings(frames=frames, flush=flush, check_registration=check_registration),
            options, progress=progress, status=status, reference=reference,
            reference_exposure_us=REFERENCE_EXPOSURE_US,
        )
    except ThinTactError as err:
        if not (bundle_dir / CAPTURE_DIR / "manifest.json").is_file():
            raise
        hint = f"{err} (captured frames are kept in {bundle_dir / CAPTURE_DIR}; run again to resume)"
        try:
            wrapped = type(err)(hint)
        except TypeError:
            raise err from None
        raise wrapped from None
