"""Where a decoder's calibration comes from (settings, profile, or the newest virtual bundle)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from thintact_sdk.device.cameras import camera_is_simulated
from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.reconstruction.bundle import CalibrationBundle, find_latest


def calibration_roots() -> list[Path]:
    """Directories searched for ``<profile>/<timestamp>/`` bundles, in order: those of
    ``$THINTACT_CALIBRATION_PATH``, ``./calibrations`` and the bundles packaged with the SDK
    (the core's lookup, ``thintact_sdk.algorithms.calibration_roots``)."""
    from thintact_sdk.tactile.calibration.store import calibration_roots as core_roots

    return core_roots()


def resolve_bundle(profile: Profile, settings: dict[str, Any]) -> CalibrationBundle:
    """The calibration bundle a decoder should use.

    Order: ``settings["bundle"]`` (a :class:`CalibrationBundle` object), ``settings["calibration"]``
    (a directory), ``profile.decoder.calibration`` (resolved against the profile file), and, for
    a profile whose camera is ``virtual``, the newest bundle under ``calibrations/<profile.name>/``.
    """
    obj = settings.get("bundle")
    if obj is not None:
        if not isinstance(obj, CalibrationBundle):
            raise CalibrationError(f"settings['bundle'] must be a CalibrationBundle, got {type(obj).__name__}")
        bundle = obj
    elif settings.get("calibration"):
        bundle = CalibrationBundle.load(Path(str(settings["calibration"])).expanduser())
    elif profile.decoder is not None and profile.decoder.calibration:
        bundle = CalibrationBundle.load(profile.resolve_path(profile.decoder.calibration))
    elif camera_is_simulated(profile):
        for root in calibration_roots():
            if (root / profile.name).is_dir():
                try:
                    bundle = CalibrationBundle.load(find_latest(root / profile.name))
                    break
                except CalibrationError:
                    continue
        else:
            raise CalibrationError(
                f"no calibration bundle for virtual profile {profile.name!r} under "
                f"{', '.join(str(r) for r in calibration_roots())}; make one with "
                f"`python tools/make_virtual_calibration.py {profile.name} --out DIR` from the "
                "SDK's source repository and put DIR in THINTACT_CALIBRATION_PATH"
            )
    else:
        raise CalibrationError(
            f"profile {profile.name!r} names no calibration: set decoder.calibration to a bundle "
            "directory (thintact calibrate writes one) or pass settings={'calibration': DIR}"
        )
    bundle.check_shapes(profile)
    return bundle
