"""Where a device's tactile LUT lives: ``calibrations/<device>/tactile/lut.npz`` (+ ``.json``).

The calibrations root is ``$THINTACT_CALIBRATIONS`` when set, else ``./calibrations`` when
that directory exists in the working directory, else the ``calibrations/`` directory of the
source checkout the SDK runs from.
"""

from __future__ import annotations

import os
from pathlib import Path

from thintact_sdk.profile import Profile
from thintact_sdk.tactile.photometric import PhotometricLUT

LUT_NAME = "lut.npz"


def calibrations_root() -> Path:
    """The directory holding ``<device>/`` calibration folders."""
    env = os.environ.get("THINTACT_CALIBRATIONS")
    if env:
        return Path(env).expanduser()
    cwd = Path.cwd() / "calibrations"
    if cwd.is_dir():
        return cwd
    return Path(__file__).resolve().parents[2] / "calibrations"


def device_lut_path(profile: Profile, root: Path | None = None) -> Path:
    """``<root>/<profile.name>/tactile/lut.npz`` (whether or not it exists)."""
    return (root or calibrations_root()) / profile.name / "tactile" / LUT_NAME


def find_lut(profile: Profile, root: Path | None = None) -> Path | None:
    """The LUT file for ``profile``: ``tactile.lut`` (relative to the profile file) if set,
    else the device's calibrations folder; None when neither exists."""
    if profile.tactile is not None and profile.tactile.lut:
        p = profile.resolve_path(profile.tactile.lut)
        return p if p.is_file() else None
    p = device_lut_path(profile, root)
    return p if p.is_file() else None


def save_device_lut(lut: PhotometricLUT, profile: Profile, root: Path | None = None) -> Path:
    """Store ``lut`` as the device's LUT; returns the ``.npz`` path."""
    return lut.save(device_lut_path(profile, root))


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
    return PhotometricLUT.load(p)
