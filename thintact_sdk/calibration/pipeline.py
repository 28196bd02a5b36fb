"""From a recording with slit frames to a calibration bundle: solve, train, validate, save.

Used by both ``thintact calibrate --from-recording`` and the wizard (which records first).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.calibration.capture_worker import Prepared
from thintact_sdk.calibration.collect import (
    Progress,
    SlitCollection,
    collect_slits,
    signal_of,
    white_frame_signal,
)
from thintact_sdk.calibration.gauge import operator_error, term_errors
from thintact_sdk.calibration.health import HealthReport, NoiseEstimate, assess, measure_noise
from thintact_sdk.calibration.lowrank import DEFAULT_RANK
from thintact_sdk.calibration.outcome import CalibrationOutcome
from thintact_sdk.calibration.prediction import (
    Prediction,
    PredictionDesign,
    design_for_prediction,
    predict_from_design,
)
from thintact_sdk.calibration.registration import RegistrationResult
from thintact_sdk.calibration.selection import (
    TauSelection,
    has_noise_curves,
    noise_curves_of,
    select,
    validation_frames,
)
from thintact_sdk.calibration.solver import (
    ChannelMatrices,
    Method,
    SolveReport,
    solve_collection,
)
from thintact_sdk.calibration.stages import STAGE_DIR, Checkpoints, StageLog, fingerprint
from thintact_sdk.calibration.tau import TauCurve
from thintact_sdk.calibration.validation import (
    TAU_GRID,
    ValidationResult,
    averaged_noise,
    choose_tau,
    make_decoder,
    needs_joint_filter,
    score,
)
from thintact_sdk.calibration.verdict import judge
from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import CalibrationLimits, Profile
from thintact_sdk.formats.recording import Recording
from thintact_sdk.host.blas import blas_threads
from thintact_sdk.reconstruction.bundle import CalibrationBundle
from thintact_sdk.reconstruction.scene_prior import ScenePrior
from thintact_sdk.reconstruction.t2s import SystemMatrices


@dataclass
class CalibrationOptions:
    """Settings of a calibration solve.

    Attributes
    ----------
    method
        ``"lsq"`` (joint least squares, default) or ``"paper"`` (Algorithm 1 verbatim).
    max_iter, tol
        Refinement (Algorithm 3) limits.
    rank
        Rank kept per slit image.
    frame_gains
        ``off`` (default), ``auto`` or ``on``: per-slit-frame gains from the white frame
        (unrecorded exposure or brightness drift, :mod:`thintact_sdk.calibration.sumrule`).
        The fit is exact on clean data but ill-conditioned (neighbouring slits look alike),
        so noise leaks into it: use it only on well-averaged recordings.
    tau
        Tikhonov τ stored in the bundle (DN²); None chooses it on the unit's own validation
        frames (:mod:`thintact_sdk.calibration.selection`).
    filter_steps
        Adam steps of the joint-filter training after its closed form (default 0, the
        closed form only, as ``thintact calibrate --filter-steps``: docs/calibration.md shows
        the held-out figures of 0, 25 and 100 steps).
    filter_scenes
        Number of training scenes for the filter.
    decoder
        Decoder used for validation; None compares the candidates of
        :func:`thintact_sdk.calibration.validation.calibration_decoders` and recommends the best.
    predict
        Predict each validation scene's PSNR from the profile and fail a unit that falls short
        of it by more than ``calibration_limits.psnr_margin_db``.
    frames_averaged
        Frames averaged per pattern (sets the noise for τ and filter training); None reads
        it from the recording (``frames`` per frame) or assumes 1.
    """

    method: Method = "lsq"
    max_iter: int = 50
    tol: float = 1e-7
    rank: int = DEFAULT_RANK
    frame_gains: str = "off"
    tau: float | None = None
    filter_steps: int = 0
    filter_scenes: int = 32
    decoder: str | None = None
    frames_averaged: int | None = None
    predict: bool = True


def channel_matrices(sm: SystemMatrices, c: int) -> ChannelMatrices:
    """Channel ``c`` of REC's :class:`SystemMatrices` as float64 :class:`ChannelMatrices`."""
    po, qo, pc, qc = (np.asarray(a, np.float64) for a in sm.channel(c))
    return ChannelMatrices(po, qo, pc, qc)


def solve_matrices(
    collection: SlitCollection, options: CalibrationOptions, profile: Profile
) -> tuple[SystemMatrices, list[SolveReport]]:
    """Algorithms 2-3 for every channel of ``collection``."""
    return solve_collection(collection, profile, options.method, options.max_iter, options.tol)


def _frames_averaged(recording: Recording, options: CalibrationOptions) -> int:
    if options.frames_averaged is not None:
        return max(1, int(options.frames_averaged))
    counts = [f.extra.get("frames") for f in recording.frames]
    nums = [int(c) for c in counts if isinstance(c, int) and c > 0]
    return int(np.median(nums)) if nums else 1


def build_bundle(
    profile: Profile,
    sm: SystemMatrices,
    options: CalibrationOptions,
    frames_averaged: int,
    source: str,
    exposure_us: float | None,
    progress: Callable[[str], None] | None = None,
) -> tuple[CalibrationBundle, dict[str, float]]:
    """Train the joint filter on ``sm`` and choose τ: a bundle ready to decode with."""
    from thintact_sdk.reconstruction.filter_training import train_joint_filter, training_scenes

    n, m = sm.scene_shape
    noise = averaged_noise(profile.noise, frames_averaged)
    scenes = training_scenes(n, m, count=options.filter_scenes, seed=0)
    if progress:
        progress("training the joint filter")
    jf = train_joint_filter(sm, scenes, noise=noise, steps=options.filter_steps, seed=0)
    bundle = CalibrationBundle.create(
        profile, sm, jf, tau=options.tau if options.tau is not None else 1.0, source=source,
        exposure_us=exposure_us,
    )
    table: dict[str, float] = {}
    if options.tau is None:
        if progress:
            progress("choosing tau")
        tau_scenes = training_scenes(n, m, count=8, seed=1)
        tau, table = choose_tau(bundle, tau_scenes, noise)
        bundle.meta["tau"] = tau
    return bundle, table


def validate(
    recording: Recording,
    collection: SlitCollection,
    profile: Profile,
    bundle: CalibrationBundle,
    decoder: str | None = None,
) -> list[ValidationResult]:
    """Reconstruct every validation frame of ``recording`` and score it against its scene."""
    dec = make_decoder(profile, bundle, decoder)
    out = []
    for i in collection.validation:
        truth = recording.scene(i)
        if truth is None:
            continue
        signal, _ = signal_of(recording, i, collection.dark_dn, collection.exposure_us)
        est = dec.decode(signal.astype(np.float32))
        label = recording.frames[i].label or Path(recording.frames[i].measurement).stem
        result = score(label, est, truth)
        raw = np.asarray(recording.measurement(i))
        result.saturated_fraction = float(np.mean(raw >= profile.noise.saturation_dn - 1.0))
        out.append(result)
    return out


def compare_with_reference(
    recording: Recording,
    collection: SlitCollection,
    profile: Profile,
    bundle: CalibrationBundle,
    reference: SystemMatrices,
    options: CalibrationOptions,
    frames_averaged: int,
    noise: NoiseEstimate | None = None,
) -> dict[str, Any]:
    """How the calibrated matrices compare with reference ones (e.g. the simulator's fit).

    Returns per-channel gauge-free operator errors, per-term errors in the canonical gauge,
    and the validation PSNR/SSIM of a bundle built the same way from the reference. With
    ``noise`` (the unit's measured noise), the reference's decoder τ is chosen by the same
    selection as the unit's (:func:`~thintact_sdk.calibration.selection.select`), so both are
    scored held out; without it, at the τ chosen on simulated scenes.
    """
    sm = bundle.system_matrices
    out: dict[str, Any] = {"operator_error": [], "term_errors": []}
    for c in range(sm.channels):
        est, ref = channel_matrices(sm, c), channel_matrices(reference, c)
        out["operator_error"].append(operator_error(est, ref))
        out["term_errors"].append(term_errors(est, ref))
    ref_opts = CalibrationOptions(**{**options.__dict__, "tau": None})
    ref_bundle, table = build_bundle(profile, reference, ref_opts, frames_averaged, "simulator",
                                     collection.exposure_us)
    if noise is not None:
        frames = validation_frames(recording, collection, profile.noise.saturation_dn)
        ref_sel = select(profile, ref_bundle, frames, noise, decoder=options.decoder,
                         simulated=_simulated_curve(table), noise_criteria_curves=False)
        ref_val = ref_sel.verdict_validation  # plain Tikhonov, as the unit is judged
        ref_bundle.meta["tau"] = ref_sel.tau
    else:
        ref_val = validate(recording, collection, profile, ref_bundle, options.decoder)
    out["reference_tau"] = ref_bundle.tau
    out["reference_psnr_db"] = {v.label: v.psnr_db for v in ref_val}
    out["reference_ssim"] = {v.label: v.ssim for v in ref_val}
    return out


def scaled(sm: SystemMatrices, factor: float) -> SystemMatrices:
    """``sm`` with its products scaled by ``factor`` (each matrix by ``sqrt(factor)``)."""
    r = float(np.sqrt(factor))
    return SystemMatrices(sm.Po * r, sm.Qo * r, sm.Pc * r, sm.Qc * r, dict(sm.meta))


def _simulated_curve(table: dict[str, float]) -> TauCurve | None:
    """The τ table of :func:`~thintact_sdk.calibration.validation.choose_tau` as a curve."""
    if not table:
        return None
    taus = [float(t) for t in table]
    values = list(table.values())
    best = taus[int(np.argmax(values))]
    return TauCurve("simulated", taus, values, best, "mean PSNR dB",
                    f"{len(TAU_GRID)} candidates on eight simulated training scenes")


def limits_of(profile: Profile) -> CalibrationLimits:
    """The profile's ``calibration_limits`` (defaults when absent)."""
    return profile.calibration_limits or CalibrationLimits()


def _design_priors(checkpoints: Checkpoints, prepared: Prepared | None) -> dict[str, ScenePrior | None] | None:
    """The scene priors the capture worker chose on the design, checkpointed so that a run
    resumed after the capture (no worker then) narrows the prior search as the first did;
    None when neither has them (every prior is then searched)."""
    if prepared is not None and prepared.priors is not None:
        checkpoints.save_object("design_priors", prepared.priors)
        return prepared.priors
    stored = checkpoints.load_object("design_priors")
    if isinstance(stored, dict) and all(isinstance(k, str) and (v is None or isinstance(v, ScenePrior))
                                        for k, v in stored.items()):
        return stored
    return None


def calibrate_recording(
    recording: Recording,
    out_dir: str | Path,
    options: CalibrationOptions | None = None,
    *,
    source: str = "recording",
    progress: Progress | None = None,
    status: Callable[[str], None] | None = None,
    registration: RegistrationResult | None = None,
    reference: SystemMatrices | None = None,
    reference_exposure_us: float | None = None,
    report: bool = True,
    prepared: Prepared | None = None,
    capture_ended: float | None = None,
) -> CalibrationOutcome:
    """Solve, train, validate and save a calibration bundle in ``out_dir``.

    Parameters
    ----------
    recording
        Frames with slit scenes (and ideally a dark frame and validation scenes).
    out_dir
        Bundle directory to write (``calibrations/<device>/<timestamp>/`` by convention).
    options
        Solve settings.
    source
        ``calibration.json`` source field (``wizard`` or ``recording``).
    progress, status
        Per-frame progress of the slit streaming, and one-line stage messages.
    registration
        Registration result to store and report (wizard).
    reference
        Matrices to compare with (virtual devices: the simulator's two-term fit).
    reference_exposure_us
        Exposure the reference is expressed at; it is rescaled to the calibration's
        exposure when both are known (signal is linear in exposure).
    report
        Write ``report.html``.
    prepared
        What the wizard's :class:`~thintact_sdk.calibration.capture_worker.CaptureWorker`
        finished during the capture (the slit collection and solve, the prediction's design):
        used instead of computing it again (the stage is marked ``pipelined``).
    capture_ended
        ``time.monotonic()`` when the wizard wrote its last pattern: ``metrics`` then records
        ``after_last_pattern_s``, the seconds from it to the bundle on disk.
    """
    opts = options or CalibrationOptions()
    profile = recording.profile
    out = Path(out_dir)
    checkpoints = Checkpoints(out / STAGE_DIR, fingerprint(
        Path(recording.root), profile.content_hash(),
        {k: v for k, v in opts.__dict__.items()} | {"frames_averaged_resolved": _frames_averaged(recording, opts)}))
    stage_names = ["slit frames and solve", "health", "joint filter", "decoder and tau", "noise criteria"]
    if opts.predict:
        stage_names += ["prediction design", "prediction"]
    stage_names.append("bundle and report")
    log = StageLog(stage_names, status)
    k = _frames_averaged(recording, opts)
    with log.stage("slit frames and solve", "reading slit frames and solving the system matrices "
                   "(Algorithms 2-3)") as st:
        solved = checkpoints.load_solve()
        if solved is not None:
            collection, sm, reports = solved
            st["resumed"] = True
        elif prepared is not None and prepared.solved is not None:
            collection, sm, reports = prepared.solved
            st["pipelined"] = prepared.seconds
            checkpoints.save_solve(collection, sm, reports)
        else:
            collection = collect_slits(recording, rank=opts.rank, progress=progress,
                                       frame_gains=opts.frame_gains)
            sm, reports = solve_matrices(collection, opts, profile)
            checkpoints.save_solve(collection, sm, reports)
    frames = validation_frames(recording, collection, profile.noise.saturation_dn)
    want_prediction = bool(opts.predict and frames.labels)
    design_priors = _design_priors(checkpoints, prepared)

    def simulate_design() -> PredictionDesign:
        """The prediction's design at the white frame's signal level (as the wizard's)."""
        white = white_frame_signal(recording)
        return design_for_prediction(profile, sm, k, white_signal_dn=None if white is None else white[0],
                                     method=opts.method, max_iter=opts.max_iter, tol=opts.tol,
                                     rank=opts.rank)
    noise_ready: Future[NoiseEstimate] = Future()
    built: dict[str, Any] = {}  # the decoders the choice built, for the noise criteria to reuse
    # the chosen decoder's name, with the bundle when the choice told it early (while its scene
    # priors still ran: select's on_decoder), else None once the choice ended
    name_ready: Future[tuple[str, CalibrationBundle | None]] = Future()

    def health_lane() -> tuple[HealthReport, PredictionDesign | None]:
        """Health (its noise first, for the τ selection), then the prediction's design part."""
        try:
            with log.stage("health", "checking the unit's health (slit residuals, noise, defects)") as st:
                health = checkpoints.load_object("health")
                if isinstance(health, HealthReport):
                    st["resumed"] = True
                    noise_ready.set_result(health.noise)
                else:
                    noise = measure_noise(recording, collection, sm, k)
                    noise_ready.set_result(noise)
                    health = assess(recording, collection, sm, k, noise=noise)
                    checkpoints.save_object("health", health)
        except BaseException as exc:
            if not noise_ready.done():
                noise_ready.set_exception(exc)
            raise
        design = None if prepared is None else prepared.design
        if want_prediction and checkpoints.load_json("prediction") is None:
            if design is not None:  # the capture's: kept for a resume after the capture
                checkpoints.save_design(design)
            else:
                with log.stage("prediction design", "simulating the design's own calibration "
                               "(for the prediction)") as st:
                    design = checkpoints.load_design(profile)
                    if design is not None:
                        st["resumed"] = True
                    else:
                        design = simulate_design()
                        checkpoints.save_design(design)
        return health, design

    def filter_lane() -> tuple[CalibrationBundle, dict[str, float]]:
        """The joint filter, from the start: the decoder's name is certain only once the
        decoder that needs it is cross-validated, and the work that waits for the name (noise
        criteria, prediction) should run beside the scene priors, not after them. Only the
        decoders that need the filter wait for it."""
        with log.stage("joint filter", "training the joint filter") as st:
            trained = checkpoints.load_filter()
            if trained is not None:
                jf, tau_table, tau0 = trained
                bundle = CalibrationBundle.create(profile, sm, jf, tau=tau0, source=source,
                                                  exposure_us=collection.exposure_us)
                st["resumed"] = True
            else:
                bundle, tau_table = build_bundle(profile, sm, opts, k, source, collection.exposure_us)
                checkpoints.save_filter(bundle.filter, tau_table, float(bundle.meta["tau"]))
        return bundle, tau_table

    def selection_lane(lane_f: Future[tuple[CalibrationBundle, dict[str, float]]],
                       ) -> tuple[CalibrationBundle, dict[str, float], TauSelection]:
        """The decoder and τ, beside the joint filter's training: the decoders that need no
        filter are built on the matrices alone and cross-validated meanwhile."""
        try:
            out = choose(lane_f)
        except BaseException as exc:
            if not name_ready.done():
                name_ready.set_exception(exc)
            raise
        if not name_ready.done():
            name_ready.set_result((out[2].decoder, None))
        return out

    def choose(lane_f: Future[tuple[CalibrationBundle, dict[str, float]]],
               ) -> tuple[CalibrationBundle, dict[str, float], TauSelection]:
        with log.stage("decoder and tau", "choosing the decoder and tau on the validation frames") as st:
            selection = checkpoints.load_object("selection")
            if isinstance(selection, TauSelection):
                st["resumed"] = True
            else:
                # the filter-free decoders' bundle: the matrices, with the τ a bundle has before
                # its τ is chosen on simulated scenes (build_bundle)
                matrices_only = CalibrationBundle.create(
                    profile, sm, None, tau=opts.tau if opts.tau is not None else 1.0, source=source,
                    exposure_us=collection.exposure_us)
                # GCV and discrepancy only where the choice needs them; else they are reported
                # and computed by noise_curves, beside the prediction: from the moment the
                # decoder's name is certain, beside the scene priors still being chosen
                selection = select(profile, matrices_only, frames, noise_ready.result, decoder=opts.decoder,
                                   tau=opts.tau, simulated=lambda: _simulated_curve(lane_f.result()[1]),
                                   noise_criteria_curves=False, built=built,
                                   on_decoder=lambda name: name_ready.set_result(
                                       (name, None if needs_joint_filter(name) else matrices_only)),
                                   filtered=lambda: lane_f.result()[0],
                                   design_priors=design_priors)
                for name in list(built):  # the noise criteria may be clearing it meanwhile
                    if name != selection.decoder:
                        built.pop(name, None)  # only the chosen one is reused
                checkpoints.save_object("selection", selection)
        bundle, tau_table = lane_f.result()
        return bundle, tau_table, selection

    def noise_curves(lane_a: Future[tuple[CalibrationBundle, dict[str, float], TauSelection]]) -> None:
        """The GCV and discrepancy curves of the chosen decoder (reported beside the choice),
        beside the prediction; started as soon as the decoder's name is certain."""
        if not frames.signals or opts.tau is not None:
            return
        name, early_bundle = name_ready.result()
        if early_bundle is None:  # told when the choice ended: it may hold the curves already
            if has_noise_curves(lane_a.result()[2]):
                return
        with log.stage("noise criteria", "GCV and discrepancy curves of the chosen decoder") as st:
            stored = checkpoints.load_object("noise_criteria")
            if isinstance(stored, list) and stored and all(isinstance(c, TauCurve) for c in stored):
                curves = stored
                st["resumed"] = True
            else:
                bundle = early_bundle if early_bundle is not None else lane_a.result()[0]
                curves = noise_curves_of(profile, bundle, frames, noise_ready.result(), name,
                                         decoder=built.get(name))
                built.clear()
                checkpoints.save_object("noise_criteria", curves)
        selection = lane_a.result()[2]
        if not has_noise_curves(selection):
            selection.curves += curves

    def predict(lane_b: Future[tuple[HealthReport, PredictionDesign | None]]) -> Prediction | None:
        """The prediction for the chosen decoder, beside the noise criteria."""
        if not opts.predict:
            return None
        name, _ = name_ready.result()  # the prediction depends on the decoder's name alone
        _, design = lane_b.result()
        with log.stage("prediction", "predicting what this design should reach") as st:
            if not frames.labels:
                return None
            stored = checkpoints.load_json("prediction")
            if stored is not None and stored.get("decoder") == name:
                st["resumed"] = True
                return Prediction(dict(stored["psnr_db"]), list(stored["gains_dn_per_unit"]),
                                  float(stored["tau"]), dict(stored["notes"]))
            if design is None:
                design = simulate_design()
            prediction = predict_from_design(
                profile, design, frames.labels, frames.truths, name,
                filter_steps=opts.filter_steps, filter_scenes=opts.filter_scenes)
            checkpoints.save_json("prediction", {
                "decoder": name, "psnr_db": prediction.psnr_db,
                "gains_dn_per_unit": prediction.gains_dn_per_unit, "tau": prediction.tau,
                "notes": prediction.notes})
            return prediction

    # lanes with one BLAS thread each: the health check (and the prediction's simulated design)
    # beside the τ selection (itself two threads: selection.SELECT_WORKERS) and the joint
    # filter; the reported noise criteria wait for the decoder's name and then run beside the
    # scene priors, and the prediction takes the next lane to come free
    with blas_threads(1), ThreadPoolExecutor(max_workers=4, thread_name_prefix="calibrate") as pool:
        lane_b = pool.submit(health_lane)
        lane_f = pool.submit(filter_lane)
        lane_a = pool.submit(selection_lane, lane_f)
        lane_c = pool.submit(noise_curves, lane_a)
        lane_d = pool.submit(predict, lane_b)
        bundle, tau_table, selection = lane_a.result()
        health, design = lane_b.result()
        lane_c.result()
        prediction = lane_d.result()
    selection.write_taus(bundle.meta)
    bundle.meta["decoder"] = selection.decoder
    val = selection.validation
    lim = limits_of(profile)
    # the unit against its design, both with plain Tikhonov (``TauSelection.verdict_validation``)
    verdict = judge(selection.verdict_validation, prediction, health, lim, registration)
    passed = verdict.passed
    mean_psnr = float(np.mean([v.psnr_db for v in val])) if val else float("nan")
    mean_ssim = float(np.mean([v.ssim for v in val])) if val else float("nan")
    metrics: dict[str, Any] = {
        "psnr_db": {v.label: v.psnr_db for v in val},
        "judged_psnr_db": {v.label: v.psnr_db for v in selection.verdict_validation},
        "ssim": {v.label: v.ssim for v in val},
        "mean_psnr_db": mean_psnr,
        "mean_ssim": mean_ssim,
        "limits": {"psnr_margin_db": lim.psnr_margin_db, "min_psnr_db": lim.min_psnr_db,
                   "min_ssim": lim.min_ssim},
        "passed": passed,
        "verdict": verdict.to_json(),
        "predicted_psnr_db": None if prediction is None else
        {k_: round(v, 3) for k_, v in prediction.psnr_db.items()},
        "health": health.to_json(),
        "solve": [
            {
                "channel": ch.meta.get("channel", str(c)),
                "method": opts.method,
                "iterations": r.iterations,
                "converged": r.converged,
                "relative_residual": r.final_residual,
                "residual_history": r.residual_history,
            }
            for c, (ch, r) in enumerate(zip(collection.channels, reports, strict=True))
        ],
        "slit_frames": collection.slit_frames,
        "frames_averaged": k,
        "dark": collection.dark_source,
        "saturated_frames": {
            **{recording.frames[i].label or str(i): f for i, f in collection.saturated.items()},
            **{v.label: v.saturated_fraction for v in val if v.saturated_fraction > 0},
        },
        "exposure_normalised_frames": len(collection.frame_scale),
        "tau_selection": selection.to_json(),
    }
    if collection.frame_gains:
        metrics["frame_gains"] = collection.frame_gains
    if registration is not None:
        metrics["registration"] = registration.to_json()
    ref_info: dict[str, Any] = {}
    if reference is not None:
        if status:
            status("comparing with the reference matrices")
        if reference_exposure_us and collection.exposure_us:
            reference = scaled(reference, collection.exposure_us / reference_exposure_us)
        ref_opts = CalibrationOptions(**{**opts.__dict__, "decoder": selection.decoder})
        ref_info = compare_with_reference(recording, collection, profile, bundle, reference, ref_opts, k,
                                          health.noise)
        metrics["reference"] = ref_info
    if not val:
        metrics["warning"] = "the recording has no validation frames (scenes that are neither dark nor slits)"
    bundle.meta["recording"] = str(recording.root)
    with log.stage("bundle and report", "writing the bundle and its report"):
        metrics["stages"] = log.to_json()  # this stage's own entry is added below
        bundle.meta["metrics"] = metrics
        outcome = CalibrationOutcome(bundle, out, reports, collection, val, passed, registration, ref_info,
                                     tau_table, selection, health, prediction, verdict)
        if report:
            from thintact_sdk.calibration.unit_report import write_report

            out.mkdir(parents=True, exist_ok=True)
            write_report(outcome, profile, out / "report.html")
    metrics["stages"] = log.to_json()
    if prepared is not None:
        metrics["pipelined"] = {"seconds": prepared.seconds, "errors": prepared.errors,
                                "solve": prepared.solved is not None,
                                "prediction_design": prepared.design is not None}
    if capture_ended is not None:  # written into calibration.json below: its own time not counted
        metrics["after_last_pattern_s"] = round(time.monotonic() - capture_ended, 3)
    try:
        bundle.save(out)  # calibration.json last: its presence marks the bundle finished
    except OSError as err:
        raise CalibrationError(f"cannot write the calibration bundle to {out}: {err}") from None
    checkpoints.remove()
    return outcome


def bundle_from_matrices(
    profile: Profile,
    sm: SystemMatrices,
    out_dir: str | Path,
    options: CalibrationOptions | None = None,
    recording: Recording | None = None,
) -> CalibrationBundle:
    """A bundle (source ``import``) around matrices calibrated elsewhere.

    The joint filter is trained on them as for a calibration. τ and the decoder are chosen
    on ``recording``'s validation frames (scenes that are neither dark nor slits; its dark
    frames, else the black level, subtracted) when one is given and holds enough of them,
    else on simulated training scenes.
    """
    from thintact_sdk.calibration.classify import classify_scene, is_dark, is_slit
    from thintact_sdk.calibration.collect import dark_level
    from thintact_sdk.simulation.noise import QUANTISATION_VARIANCE_DN2

    opts = options or CalibrationOptions()
    k = _frames_averaged(recording, opts) if recording is not None else max(1, opts.frames_averaged or 1)
    bundle, table = build_bundle(profile, sm, opts, k, "import", None)
    simulated = _simulated_curve(table)
    metrics: dict[str, Any] = {"tau_selection": {"criterion": "simulated"} if simulated is None else
                               {"criterion": "simulated", "tau": simulated.tau}}
    if recording is not None:
        dark, source = dark_level(recording)
        val = [i for i in range(len(recording)) if (scene := recording.scene(i)) is not None
               and not is_dark(r := classify_scene(scene)) and not is_slit(r)]
        collection = SlitCollection([], dark, source, None, val)
        frames = validation_frames(recording, collection, profile.noise.saturation_dn)
        nz = profile.noise
        noise = NoiseEstimate(nz.read_noise_dn, nz.electrons_per_dn, nz.read_noise_dn, nz.electrons_per_dn,
                              (nz.read_noise_dn**2 + QUANTISATION_VARIANCE_DN2) / k, 1.0 / (nz.electrons_per_dn * k))
        selection = select(profile, bundle, frames, noise, decoder=opts.decoder, tau=opts.tau, simulated=simulated)
        selection.write_taus(bundle.meta)
        bundle.meta["decoder"] = selection.decoder
        metrics = {"tau_selection": selection.to_json(),
                   "psnr_db": {v.label: v.psnr_db for v in selection.validation},
                   "ssim": {v.label: v.ssim for v in selection.validation}}
        bundle.meta["recording"] = str(recording.root)
    bundle.meta["metrics"] = metrics
    bundle.meta["imported_from"] = sm.meta.get("imported_from")
    try:
        bundle.save(Path(out_dir))
    except OSError as err:
        raise CalibrationError(f"cannot write the calibration bundle to {out_dir}: {err}") from None
    return bundle
