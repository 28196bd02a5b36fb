"""The mask's pose from a flat field file: the library behind ``thintact calibrate-pose``.

:func:`flat_field_signal` reads a flat field (a recording's all-white frame minus its dark
frames, or an ``R × S(× C)`` ``.npy`` of raw DN minus the profile's black level);
:func:`pose_from_flat_field` reads it and runs
:func:`thintact_sdk.calibration.pose.estimate_pose` on it. The command only parses, prints
the estimate and writes the profile.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thintact_sdk.calibration.collect import white_frame_signal
from thintact_sdk.calibration.pose import PoseEstimate, Progress, Unknown, estimate_pose
from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import Profile

__all__ = ["FlatFieldPose", "flat_field_signal", "pose_from_flat_field"]


def flat_field_signal(path: str | Path, profile: Profile) -> tuple[np.ndarray, str]:
    """``(signal, where it came from)``: the flat field at ``path`` in DN above black,
    ``R × S × C`` (a recording's first all-white frame minus its dark level) or as stored
    (``R × S`` or ``R × S × C`` ``.npy`` of raw DN, minus ``profile``'s black level), float64.

    Raises
    ------
    CalibrationError
        A recording without an all-white frame, a path that is neither a recording directory
        nor an existing ``.npy`` file, or an unreadable or non-numeric array (named by file).
    """
    from thintact_sdk.formats.recording import Recording
    from thintact_sdk.formats.safe_arrays import (
        read_npy,  # header first: no pickle, no huge allocation
    )

    path = Path(path)
    if path.is_dir():
        white = white_frame_signal(Recording(path))
        if white is None:
            raise CalibrationError(f"recording {path} has no all-white frame to use as a flat field")
        return white[0], white[2]
    if path.suffix != ".npy" or not path.is_file():
        raise CalibrationError(f"flat field {path}: expected a recording directory or an existing .npy file")
    raw = read_npy(path, what="flat field", error=CalibrationError, kinds="uif").astype(np.float64)
    return raw - profile.noise.black_level_dn, f"{path.name} minus the black level"


@dataclass(frozen=True)
class FlatFieldPose:
    """What :func:`pose_from_flat_field` found: the ``estimate`` and the flat field's ``source``
    (which frame or file, and what was subtracted)."""

    estimate: PoseEstimate
    source: str


def pose_from_flat_field(
    path: str | Path,
    profile: Profile,
    unknown: Unknown = "z",
    bounds: tuple[float, float] | None = None,
    *,
    progress: Progress | None = None,
) -> FlatFieldPose:
    """The mask's pose in ``profile``'s device from the flat field at ``path``
    (:func:`flat_field_signal`), as ``thintact calibrate-pose`` estimates it. ``unknown`` and
    ``bounds`` (mm for z, µm for the pitch) as :func:`~thintact_sdk.calibration.pose.estimate_pose`;
    ``progress`` receives a line after the flat field is read and the estimator's lines.

    Raises
    ------
    CalibrationError
        ``bounds`` not ``0 < LOW <= HIGH`` (named as ``--bounds``), or a flat field that cannot
        be read (:func:`flat_field_signal`).
    """
    if bounds is not None and not 0 < bounds[0] <= bounds[1]:
        raise CalibrationError(f"--bounds: need 0 < LOW <= HIGH, got {bounds[0]} {bounds[1]}")
    signal, source = flat_field_signal(path, profile)
    if progress is not None:
        progress(f"read the flat field {path}")
    est = estimate_pose(signal, profile, unknown=unknown,
                        bounds=None if bounds is None else (bounds[0], bounds[1]), progress=progress)
    return FlatFieldPose(est, source)
