"""Where a device's tactile LUT lives: ``calibrations/<device>/tactile/lut.npz`` (+ ``.json``).

Same roots as the decoders' calibration bundles (:func:`calibration_roots`, in this order):
every directory of ``$THINTACT_CALIBRATION_PATH`` (``os.pathsep``-separated) when set, then
``./calibrations`` when that directory exists in the working directory, then the bundles
shipped inside the package (:data:`PACKAGED_CALIBRATIONS`, ``thintact_sdk/data/calibrations``:
the virtual devices' decoder bundles and tactile LUTs, so a ``pip install`` works from any
directory). A LUT or bundle is looked up in all of them, in that order. New LUTs are written
under :func:`user_calibrations_root`, never into the packaged ones.
"""

from __future__ import annotations

import os
from pathlib import Path

from thintact_sdk.device.cameras import camera_is_simulated
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT

LUT_NAME = "lut.npz"
PACKAGED_CALIBRATIONS = Path(__file__).resolve().parents[2] / "data" / "calibrations"
"""The calibrations shipped as package data (``<device>/<timestamp>/`` bundles and
``<device>/tactile/lut.npz``) of the virtual profiles; last in :func:`calibration_roots`."""


def calibration_roots() -> list[Path]:
    """Directories searched for ``<device>/`` calibration folders, in order: the user's
    (``$THINTACT_CALIBRATION_PATH``), ``./calibrations`` when it exists, the packaged ones."""
    env = [Path(d).expanduser() for d in os.environ.get("THINTACT_CALIBRATION_PATH", "").split(
        os.pathsep) if d]
    cwd = Path.cwd() / "calibrations"
    roots = env + ([cwd] if cwd.is_dir() else []) + [PACKAGED_CALIBRATIONS]
    return list(dict.fromkeys(roots))


def calibrations_root() -> Path:
    """The directory new calibrations are written to (first of :func:`calibration_roots`)."""
    return calibration_roots()[0]


def user_calibrations_root() -> Path:
    """Where a new calibration is written: the first directory of ``$THINTACT_CALIBRATION_PATH``
    when set, else ``./calibrations`` (created on write), so that the LUTs shipped with the
    package are never replaced by a calibration run."""
    env = [d for d in os.environ.get("THINTACT_CALIBRATION_PATH", "").split(os.pathsep) if d]
    return Path(env[0]).expanduser() if env else Path.cwd() / "calibrations"


def device_lut_path(profile: Profile, root: Path | None = None) -> Path:
    """``<root>/<profile.name>/tactile/lut.npz`` (whether or not it exists)."""
    return (root or calibrations_root()) / profile.name / "tactile" / LUT_NAME


def find_lut(profile: Profile, root: Path | None = None) -> Path | None:
    """The LUT file for ``profile``: ``tactile.lut`` (relative to the profile file) if set,
    else the device's folder under ``root`` or the first of :func:`calibration_roots` that
    has one; None when there is none."""
    if profile.tactile is not None and profile.tactile.lut:
        p = profile.resolve_path(profile.tactile.lut)
        return p if p.is_file() else None
    for r in [root] if root is not None else calibration_roots():
        p = device_lut_path(profile, r)
        if p.is_file():
            return p
    return None


FORCE_NAME = "force.json"


def force_calibration_path(profile: Profile, root: Path | None = None) -> Path:
    """``<root>/<profile.name>/tactile/force.json`` (whether or not it exists; default root:
    :func:`user_calibrations_root`, where ``thintact calibrate-force`` writes)."""
    return (root or user_calibrations_root()) / profile.name / "tactile" / FORCE_NAME


def find_force_calibration(profile: Profile) -> Path | None:
    """The device's stored force gains (``thintact calibrate-force``): the first
    ``<device>/tactile/force.json`` of :func:`calibration_roots`; None when there is none."""
    for r in calibration_roots():
        p = force_calibration_path(profile, r)
        if p.is_file():
            return p
    return None


def save_device_lut(lut: PhotometricLUT, profile: Profile, root: Path | None = None) -> Path:
    """Store ``lut`` as the device's LUT (under ``root``, default
    :func:`user_calibrations_root`); returns the ``.npz`` path."""
    return lut.save(device_lut_path(profile, root or user_calibrations_root()))


def load_device_lut(profile: Profile, root: Path | None = None) -> PhotometricLUT | None:
    """The device's stored LUT, or None when it has none."""
    p = find_lut(profile, root)
    if p is None:
        if profile.tactile is not None and profile.tactile.lut:
            from thintact_sdk.errors import CalibrationError

            raise CalibrationError(
                f"profile {profile.name!r} names tactile.lut {profile.tactile.lut!r} but "
                f"{profile.resolve_path(profile.tactile.lut)} does not exist"
            )
        return None
    lut = PhotometricLUT.load(p)
    from thintact_sdk.tactile.interpretation.grid import (
        TactileParams,
        binned_params,
        working_factor,
    )

    params = TactileParams.from_profile(profile)
    work_mm = binned_params(params, working_factor(params)).mm_per_px
    stored = lut.meta.get("work_mm_per_px")
    if stored is not None and abs(float(stored) - work_mm) > 0.01 * work_mm:
        from thintact_sdk.errors import CalibrationError

        raise CalibrationError(
            f"tactile LUT {p} was calibrated on {float(stored):.4f} mm pixels but profile "
            f"{profile.name!r} works on {work_mm:.4f} mm pixels; run `thintact "
            f"calibrate-tactile --profile {profile.name}` again"
        )
    return lut


def lut_for_profile(profile: Profile, allow_simulated: bool | None = None) -> PhotometricLUT:
    """The LUT a sensor of ``profile`` uses.

    The device's stored LUT when there is one; otherwise, when ``allow_simulated`` (default:
    when the profile's camera is the virtual one), a LUT calibrated on the tactile
    simulator's own scenes (:func:`thintact_sdk.tactile.calibration.ball_press.scene_level_lut`).

    Raises
    ------
    CalibrationError
        When there is no stored LUT and a simulated one is not allowed.
    """
    lut = load_device_lut(profile)
    if lut is not None:
        return lut
    if allow_simulated is None:
        allow_simulated = camera_is_simulated(profile)
    if not allow_simulated:
        from thintact_sdk.errors import CalibrationError

        raise CalibrationError(
            f"no tactile LUT for device {profile.name!r} (looked for "
            f"{device_lut_path(profile)}); run `thintact calibrate-tactile --profile "
            f"{profile.name}` with a ball press"
        )
    from thintact_sdk.tactile.calibration.ball_press import scene_level_lut

    return scene_level_lut(profile)
