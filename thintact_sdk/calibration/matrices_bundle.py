"""Bundles around system matrices made without a slit scan: imported or directly generated.

The libraries behind ``thintact calibrate-import`` (:func:`import_calibration`: Po, Qo, Pc, Qc
or FlatCam Φ calibrated elsewhere) and ``thintact calibrate-direct`` (:func:`direct_calibration`:
the paper's direct generation from the profile's mask design and pose, scaled to DN by a
recording's white frame). Both end in
:func:`thintact_sdk.calibration.pipeline.bundle_from_matrices` (joint filter training, τ and
the decoder chosen on the recording's validation frames, the bundle written); the commands
only parse, call one function and print.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thintact_sdk.calibration.classify import classify_scene, is_dark, is_slit
from thintact_sdk.calibration.collect import white_frame_signal
from thintact_sdk.calibration.pipeline import CalibrationOptions, bundle_from_matrices
from thintact_sdk.calibration.tau import MIN_SCENES_PER_FOLD
from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.formats.recording import Recording
from thintact_sdk.reconstruction.bundle import CalibrationBundle
from thintact_sdk.reconstruction.t2s import SystemMatrices

__all__ = [
    "DirectCalibration",
    "direct_calibration",
    "import_calibration",
    "validation_scene_count",
    "white_scale_dn",
]


def validation_scene_count(rec: Recording) -> tuple[int, int]:
    """``(frames, distinct scenes)`` among ``rec``'s validation frames: frames with a scene that
    is neither dark nor a slit, as :func:`thintact_sdk.calibration.pipeline.bundle_from_matrices`
    takes them (scenes compared bit for bit as float32)."""
    keys = []
    for i in range(len(rec)):
        scene = rec.scene(i)
        if scene is not None and not is_dark(r := classify_scene(scene)) and not is_slit(r):
            keys.append(hashlib.sha256(np.ascontiguousarray(scene, np.float32).tobytes()).hexdigest())
    return len(keys), len(set(keys))


def white_scale_dn(unit: SystemMatrices, rec: Recording) -> tuple[float, str]:
    """``(scale DN, where it came from)``: DN above black of a white scene through an open
    mask, from ``rec``'s white frame: the ratio of its mean (minus the dark level) to the mean
    of ``unit`` (the direct matrices at unit scale) on a white scene.

    Raises
    ------
    CalibrationError
        ``rec`` has no white (flat) frame, or its mean or the model's is not > 0 (named by
        the recording and frame).
    """
    white = white_frame_signal(rec)
    if white is None:
        raise CalibrationError(f"recording {rec.root} has no white (flat) frame to scale the matrices; "
                               "give --scale-dn")
    raw, _, source = white
    signal = float(np.mean(raw))
    model = float(np.mean(unit.forward(np.ones((*unit.scene_shape, unit.channels)))))
    if not (signal > 0 and model > 0):
        raise CalibrationError(f"{rec.root}: white {source} has mean {signal:.4g} DN; "
                               "no scale can be taken from it")
    return signal / model, f"white {source}"


@dataclass(frozen=True)
class DirectCalibration:
    """What :func:`direct_calibration` made.

    Attributes
    ----------
    bundle
        The bundle written (its ``meta["metrics"]["tau_selection"]`` says how τ was chosen).
    matrices
        The directly generated system matrices, in DN (``meta["scale_dn"]``).
    scale_dn, scale_source
        DN above black of a white scene through a fully open mask, and where it came from
        (``"--scale-dn"`` or the recording's white frame).
    validation_frames, distinct_scenes
        The recording's validation frames and their distinct scenes
        (:func:`validation_scene_count`).
    """

    bundle: CalibrationBundle
    matrices: SystemMatrices
    scale_dn: float
    scale_source: str
    validation_frames: int
    distinct_scenes: int

    @property
    def scenes_needed(self) -> int:
        """Distinct validation scenes cross-validation needs (two folds)."""
        return 2 * MIN_SCENES_PER_FOLD

    @property
    def chosen_on_the_unit(self) -> bool:
        """Whether τ and the decoder were cross-validated on the recording's own frames."""
        sel = self.bundle.meta.get("metrics", {}).get("tau_selection", {})
        return sel.get("criterion") == "cross-validation"


def direct_calibration(
    profile: Profile,
    recording: Recording,
    out: str | Path,
    options: CalibrationOptions | None = None,
    scale_dn: float | None = None,
    *,
    stage: Callable[[str], None] | None = None,
) -> DirectCalibration:
    """A bundle at ``out`` from ``profile``'s mask design and pose by direct generation, as
    ``thintact calibrate-direct`` makes it.

    The matrices (:meth:`SystemMatrices.direct`) are scaled to DN by ``scale_dn`` (DN above
    black of a white scene through a fully open mask) or, when None, by ``recording``'s white
    frame (:func:`white_scale_dn`); each matrix by ``sqrt(scale)``, so the model scales by
    ``scale``. ``stage`` receives the two stage lines (``[1/2] ...``, ``[2/2] ...``).

    Raises
    ------
    CalibrationError
        No white frame to scale by (and no ``scale_dn``), or a failure of the bundle's
        filter training or τ selection.
    """
    say = stage or (lambda _msg: None)
    say("[1/2] direct generation of the system matrices")
    unit = SystemMatrices.direct(profile, scale_dn=1.0)
    if scale_dn is not None:
        scale, source = float(scale_dn), "--scale-dn"
    else:
        scale, source = white_scale_dn(unit, recording)
    root = float(np.sqrt(scale))  # each matrix by sqrt(scale): the model by scale, as direct() does
    sm = SystemMatrices(unit.Po * root, unit.Qo * root, unit.Pc * root, unit.Qc * root,
                        {**unit.meta, "scale_dn": scale})
    sm.meta["imported_from"] = f"direct generation from profile {profile.name!r}"
    frames, distinct = validation_scene_count(recording)
    say("[2/2] filter training, tau and decoder choice, bundle")
    bundle = bundle_from_matrices(profile, sm, out, options, recording)
    return DirectCalibration(bundle, sm, scale, source, frames, distinct)


def import_calibration(
    matrices: str | Path,
    profile: Profile,
    out: str | Path,
    options: CalibrationOptions | None = None,
    recording: Recording | None = None,
) -> tuple[SystemMatrices, CalibrationBundle]:
    """``(the imported matrices, the bundle written at out)``: Po/Qo/Pc/Qc or FlatCam
    Φ_L/Φ_R from ``matrices`` (.npz or .mat, shapes checked against ``profile``,
    :func:`thintact_sdk.formats.matrices.import_matrices`), with τ and the decoder chosen on
    ``recording``'s validation frames (else on simulated scenes), as ``thintact
    calibrate-import`` makes it.

    Raises
    ------
    CalibrationError
        A matrices file that cannot be read or does not fit the profile (named by file and
        member), or a failure of the filter training or τ selection.
    """
    from thintact_sdk.formats.matrices import import_matrices

    sm = import_matrices(matrices, profile)
    return sm, bundle_from_matrices(profile, sm, out, options, recording)
