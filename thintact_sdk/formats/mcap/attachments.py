"""Which calibration files a log carries as MCAP attachments.

A log is self-describing: it attaches the profile (``profile.json``), the files of the
decoder's calibration bundle (``calibration/<file>``) and the device's photometric-stereo
LUT (``tactile/<file>``) that were in use when it was written.
"""

from __future__ import annotations

import json
from pathlib import Path

from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.reconstruction.bundle import find_latest
from thintact_sdk.tactile.calibration.store import calibration_roots, find_lut

MEDIA_TYPES = {".json": "application/json", ".npz": "application/x-npz",
               ".yaml": "application/yaml"}


def profile_attachment(profile: Profile) -> tuple[str, str, bytes]:
    """``(name, media type, bytes)`` of the profile as JSON."""
    text = json.dumps(profile.contract_dict(), indent=1) + "\n"
    return "profile.json", MEDIA_TYPES[".json"], text.encode()


def calibration_bundle_dir(profile: Profile) -> Path | None:
    """The decoder's calibration bundle directory, or None when the profile names none.

    Looks where the decoders look: ``decoder.settings.calibration``, ``decoder.calibration``
    (relative to the profile file), else the newest bundle under
    ``<calibration root>/<profile name>/``.
    """
    cfg = profile.decoder
    if cfg is not None and cfg.settings.get("calibration"):
        return Path(str(cfg.settings["calibration"])).expanduser()
    if cfg is not None and cfg.calibration:
        return profile.resolve_path(cfg.calibration)
    for root in calibration_roots():
        try:
            return find_latest(root / profile.name)
        except CalibrationError:
            continue
    return None


def calibration_files(profile: Profile) -> list[tuple[str, Path]]:
    """``(attachment name, file)`` for the calibration bundle and the tactile LUT in use."""
    files: list[tuple[str, Path]] = []
    bundle = calibration_bundle_dir(profile)
    if bundle is not None and bundle.is_dir():
        files += [(f"calibration/{p.name}", p) for p in sorted(bundle.iterdir()) if p.is_file()]
    lut = find_lut(profile)
    if lut is not None:
        for p in (lut, lut.with_suffix(".json")):
            if p.is_file():
                files.append((f"tactile/{p.name}", p))
    return files


def media_type(path: Path) -> str:
    """The attachment media type of a calibration file."""
    return MEDIA_TYPES.get(path.suffix.lower(), "application/octet-stream")
