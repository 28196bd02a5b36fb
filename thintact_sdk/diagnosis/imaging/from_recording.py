"""Diagnose a recording as ``thintact diagnose`` does: one call, the command's whole report.

:func:`diagnose_recording` reads a ``thintact-recording/1`` directory once, bins a large
sensor (:func:`~thintact_sdk.diagnosis.imaging.binning.auto_bin_factor`), holds what the
simulator cannot build on this device (:func:`~thintact_sdk.diagnosis.imaging.binning.screening_limits`),
runs the engine (:func:`~thintact_sdk.diagnosis.imaging.engine.diagnose`) with the binned
data's stages (unbinned amplitudes, the unbinned stage, the mask angle on coarser blocks),
and completes the report: hotspots in unbinned pixels, ``binned``, ``full_size``,
``not_screened``, ``saturated_frames``. The command only parses, calls it, prints and writes
(:func:`~thintact_sdk.diagnosis.imaging.outputs.write_outputs`).

:func:`diagnose` is the package's entry point: a path is diagnosed this way; a
:class:`~thintact_sdk.diagnosis.imaging.recording_data.DiagnosisData` the caller already
loaded (and binned, with the stages it chose in the options) goes to the engine as given.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

from thintact_sdk.diagnosis.imaging.binning import (
    auto_bin_factor,
    bin_data,
    binned_variance_fn,
    full_size_check,
    screening_limits,
    simulate_float32,
    unbin_hotspots,
    unbinned_amplitude_fn,
)
from thintact_sdk.diagnosis.imaging.coarse_angle import CoarseAngleInput
from thintact_sdk.diagnosis.imaging.engine import DiagnoseOptions, Diagnosis, known_candidates
from thintact_sdk.diagnosis.imaging.engine import diagnose as diagnose_data
from thintact_sdk.diagnosis.imaging.forward_model import SimulateFn
from thintact_sdk.diagnosis.imaging.recording_data import DiagnosisData, load_diagnosis_data
from thintact_sdk.diagnosis.imaging.stats import VarianceFn
from thintact_sdk.diagnosis.imaging.unbinned import UnbinnedInput
from thintact_sdk.diagnosis.imaging.window_check import window_check
from thintact_sdk.errors import ThinTactError

Say = Callable[[str], None]
"""A sink for one line of text (progress, a note, a warning)."""

ANGLE = "mask_misalignment.angle_deg"
"""The held parameter the coarse-angle stage can screen after all."""


@dataclass
class RecordingOptions(DiagnoseOptions):
    """:class:`~thintact_sdk.diagnosis.imaging.engine.DiagnoseOptions` plus the choices of
    ``thintact diagnose`` (defaults are the command's).

    Attributes
    ----------
    bin_factor
        Diagnose the sensor binned ``b × b`` (0: automatic, binning a sensor above
        :data:`~thintact_sdk.diagnosis.imaging.binning.MAX_DIAGNOSIS_PIXELS`; 1: never).
    unbinned_check
        After a binned diagnosis, evaluate the fit on the unbinned recording and run the
        unbinned stage (effects finer than a block).
    coarse_angle_check
        When the mask angle is held on the binned data, fit it on coarser blocks after the
        selection.

    ``candidates``, ``held_params``, ``fine_amplitude``, ``unbinned`` and ``coarse_angle``
    are set by :func:`diagnose_recording` from the recording (what the caller gives there is
    replaced where the device needs it: the screening limits, the binned stages).
    """

    bin_factor: int = 0
    unbinned_check: bool = True
    coarse_angle_check: bool = True


def check_finite_report(report: dict[str, Any]) -> None:
    """Refuse a report whose headline figures are NaN/Inf (never a silent NaN).

    Raises
    ------
    ThinTactError
        Naming the non-finite figures (``noise_rms_dn``, ``baseline.rms_dn``, ...).
    """
    figures = {"noise_rms_dn": report.get("noise_rms_dn")}
    for part in ("baseline", "final"):
        for key in ("rms_dn", "chi2_per_dof"):
            figures[f"{part}.{key}"] = report.get(part, {}).get(key)
    bad = [k for k, v in figures.items() if not (isinstance(v, int | float) and math.isfinite(v))]
    if bad:
        raise ThinTactError(f"the diagnosis gave non-finite {', '.join(bad)} (too few usable "
                            "pixels: saturated or masked?); nothing was written")


def _quiet(_msg: str) -> None:
    """The default sink: says nothing."""


def diagnose_recording(
    recording: str | os.PathLike[str],
    options: DiagnoseOptions | None = None,
    *,
    progress: Say | None = None,
    log: Say | None = None,
    warn: Say | None = None,
) -> Diagnosis:
    """Diagnose the ``thintact-recording/1`` directory ``recording`` as ``thintact diagnose``
    does (CONTRACTS §6), returning the command's whole ``report`` (``Diagnosis.report``, what
    ``report.json`` holds) and the fitted profile at the recording's own sensor size.

    ``options``: a :class:`RecordingOptions` (a plain ``DiagnoseOptions`` takes its binning
    choices at their defaults); it is not modified. ``progress`` receives the engine's
    transient status lines, ``log`` the lines the command prints (frames read, binning,
    parameters not screened, the unbinned evaluation), ``warn`` the warnings (frames
    saturated at every pixel).

    Raises
    ------
    ThinTactError
        A recording that cannot be diagnosed (named by file, field or frame), a sensor that
        no bin factor brings under the diagnosis size, or a report with non-finite headline
        figures.
    """
    opt = options if isinstance(options, RecordingOptions) else \
        RecordingOptions(**vars(options or DiagnoseOptions()))
    say, note, warning = progress or _quiet, log or _quiet, warn or _quiet
    data = load_diagnosis_data(recording)
    note(f"{data.n_frames} frames with scenes ({data.skipped} without), "
         f"{data.profile.sensor.rows}×{data.profile.sensor.cols} sensor")
    if data.saturated_frames:
        listed = ", ".join(f"{k} ({v:g} DN)" for k, v in list(data.saturated_frames.items())[:5])
        more = f" and {len(data.saturated_frames) - 5} more" if len(data.saturated_frames) > 5 else ""
        warning(f"{len(data.saturated_frames)} frame(s) saturated at every pixel: {listed}{more}; "
                "diagnosed as data (report.json saturated_frames)")
    full_data, full_profile = data, data.profile
    b = opt.bin_factor or auto_bin_factor(full_profile.sensor.rows, full_profile.sensor.cols)
    if b > 1:
        data = bin_data(data, b)
        note(f"diagnosing the sensor binned {b}×{b}: {data.profile.sensor.rows}×"
             f"{data.profile.sensor.cols} pixels of {data.profile.sensor.pixel_pitch_um:g} um")
    engine_opts = replace(opt)
    # at every size: an effect whose kernel family is out of reach is held or dropped, and a
    # finding it could stand behind names it (a wide field of view needs this unbinned too)
    limits = screening_limits(data.profile)
    skipped: dict[str, str] = limits.not_screened
    if skipped:
        engine_opts.candidates = [c for c in known_candidates(data.profile) if c not in limits.dropped]
        engine_opts.held_params = limits.held
    if b > 1:
        engine_opts.fine_amplitude = unbinned_amplitude_fn(full_data, sys_frac=opt.sys_frac)
        if opt.unbinned_check:
            engine_opts.unbinned = UnbinnedInput(full_data, b, simulate=simulate_float32)
        if opt.coarse_angle_check and "angle_deg" in limits.held.get("mask_misalignment", ()):
            engine_opts.coarse_angle = CoarseAngleInput(full_data, b, simulate=simulate_float32)
    for name, why in skipped.items():
        later = " (fitted on coarser blocks after the selection)" if engine_opts.coarse_angle is not None \
            and name == ANGLE else ""
        note(f"not screened here: {name} ({why}){later}")
    say("diagnosing...")
    d = diagnose_data(data, variance_fn=binned_variance_fn(b) if b > 1 else None, options=engine_opts,
                      progress=say)
    rep = d.report
    if b > 1:
        unbin_hotspots(rep, b)
        rep["binned"] = {"factor": b, "rows": data.profile.sensor.rows, "cols": data.profile.sensor.cols,
                         "not_screened": skipped}
        if d.unbinned is not None:
            rep["binned"]["unbinned_stage"] = d.unbinned.to_json()
        if d.coarse_angle is not None:
            rep["binned"]["coarse_angle"] = d.coarse_angle.to_json()
            if d.coarse_angle.ran:  # screened after all, on coarser blocks
                skipped.pop(ANGLE, None)
        d.fitted_profile = full_profile.with_physics(dict(d.fitted_profile.physics))
        if opt.unbinned_check:
            note("evaluating the fit on the unbinned recording")
            rep["full_size"] = _full_size(d, full_data, opt.sys_frac, note)
    if b == 1 and skipped:  # beyond CONTRACTS §6, only when there is something to say
        rep["not_screened"] = skipped
    if full_data.saturated_frames:  # CONTRACTS §6 keys otherwise: only present when there are any
        rep["saturated_frames"] = dict(full_data.saturated_frames)
    check_finite_report(rep)
    return d


def _full_size(d: Diagnosis, full_data: DiagnosisData, sys_frac: float, note: Say) -> dict[str, Any]:
    """``report.json`` ``full_size``: the binned diagnosis's model on the unbinned recording
    (the unbinned stage's own evaluation where it changed nothing, on windows of the sensor
    where the whole sensor's kernel is refused)."""
    stage = d.unbinned
    if d.unbinned_skipped:
        note("the whole sensor's kernel is refused: checking the fit on windows of it")
        return {"not_evaluated": d.unbinned_skipped,
                "windows": window_check(full_data, d.selection.values, sys_frac).to_json()}
    if stage is not None and stage.check and not (stage.selection and stage.selection.rounds) \
            and not stage.refitted and not stage.replaced:
        return {"final": dict(stage.check)}  # the stage's own evaluation of this model
    out: dict[str, Any] = {"final": full_size_check(full_data, d.selection.values, sys_frac)}
    if stage is not None and stage.check:
        out["before_unbinned_stage"] = dict(stage.check)
    return out


def diagnose(
    recording: str | os.PathLike[str] | DiagnosisData,
    simulate: SimulateFn | None = None,
    variance_fn: VarianceFn | None = None,
    options: DiagnoseOptions | None = None,
    progress: Say | None = None,
) -> Diagnosis:
    """Diagnose a recording (CONTRACTS §6).

    A path (a ``thintact-recording/1`` directory) is diagnosed exactly as ``thintact
    diagnose`` diagnoses it (:func:`diagnose_recording`: binning, screening limits, the
    binned stages, the whole report); ``simulate`` and ``variance_fn`` must then be None
    (they follow from the binning). A
    :class:`~thintact_sdk.diagnosis.imaging.recording_data.DiagnosisData` is diagnosed as
    given by the engine (:func:`thintact_sdk.diagnosis.imaging.engine.diagnose`): the caller
    has loaded and possibly binned it and names the stages in ``options``.

    Raises
    ------
    ThinTactError
        As :func:`diagnose_recording` or the engine; for a path with ``simulate`` or
        ``variance_fn``.
    """
    if isinstance(recording, DiagnosisData):
        return diagnose_data(recording, simulate, variance_fn, options, progress)
    if simulate is not None or variance_fn is not None:
        raise ThinTactError("diagnose: simulate and variance_fn apply to loaded DiagnosisData only; "
                            "a recording path is diagnosed with the command's own")
    return diagnose_recording(recording, options, progress=progress)
