"""Which decoder and which τ the bundle recommends, chosen on the unit's own frames.

Each candidate decoder is cross-validated over the recording's validation scenes
(:func:`thintact_sdk.calibration.tau.cross_validate`); the one with the best held-out mean
PSNR is recommended (``calibration.json`` → ``decoder``) and every candidate's own τ is
stored (in the ``calibration.json`` field its trait ``tau-key`` names). GCV and the
discrepancy principle are computed for the recommended decoder and reported. When the
scenes cannot make two folds, τ is the one chosen on simulated training scenes (GCV when
there is none): on the test recordings GCV chose a τ 3-15× too small.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.calibration.collect import SlitCollection, signal_of
from thintact_sdk.calibration.health import NoiseEstimate
from thintact_sdk.calibration.tau import (
    CrossValidation,
    TauCurve,
    choose_prior,
    cross_validate,
    enough_folds,
    noise_criteria,
    prior_candidates,
    tau_grid,
)
from thintact_sdk.calibration.validation import (
    ValidationResult,
    calibration_decoders,
    default_decoder,
    make_decoder,
    needs_joint_filter,
    score,
    takes_scene_prior,
    tau_key,
)
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.formats.recording import Recording
from thintact_sdk.reconstruction.bundle import CalibrationBundle
from thintact_sdk.reconstruction.scene_prior import ScenePrior
from thintact_sdk.reconstruction.t2s import SystemMatrices


@dataclass
class ValidationFrames:
    """The recording's validation frames, ready to decode."""

    labels: list[str]
    signals: list[np.ndarray]
    truths: list[np.ndarray]
    saturated: list[float]


@dataclass
class TauSelection:
    """The recommended decoder, its τ, how they were chosen, and the held-out validation."""

    decoder: str
    tau: float
    criterion: str
    decoder_taus: dict[str, float]
    curves: list[TauCurve]
    cross_validation: dict[str, CrossValidation] = field(default_factory=dict)
    validation: list[ValidationResult] = field(default_factory=list)
    judged_validation: list[ValidationResult] | None = None
    prior_search: dict[str, str] = field(default_factory=dict)

    @property
    def verdict_validation(self) -> list[ValidationResult]:
        """What the unit is judged on against its design's prediction: the held-out results of
        plain Tikhonov (a deployed scene prior is a property of the scenes, not of the
        hardware; with it the τ cross-validation picks on a handful of scenes differs between
        the unit and its simulated design and moves single scenes by up to ±5 dB, which would
        fail healthy units), else :attr:`validation`."""
        return self.validation if self.judged_validation is None else self.judged_validation

    @property
    def channel_taus(self) -> dict[str, list[float]]:
        """Per decoder, the τ per channel cross-validation chose (only where it scored better
        held out than one τ; ``calibration.json`` → ``channel_tau``)."""
        return {name: cv.channel_tau for name, cv in self.cross_validation.items() if cv.channel_tau is not None}

    @property
    def priors(self) -> dict[str, ScenePrior]:
        """Per decoder, the scene prior cross-validation chose (only where it scored better held
        out than plain Tikhonov; ``calibration.json`` → ``scene_prior``)."""
        return {name: cv.prior for name, cv in self.cross_validation.items() if cv.prior is not None}

    def to_json(self) -> dict[str, object]:
        return {
            "decoder": self.decoder, "tau": float(f"{self.tau:.4g}"), "criterion": self.criterion,
            "decoder_taus": {k: float(f"{v:.4g}") for k, v in self.decoder_taus.items()},
            "held_out_mean_psnr_db": {k: round(v.held_out_mean_db, 3) for k, v in self.cross_validation.items()},
            "tau_bootstrap_68": {k: [float(f"{t:.4g}") for t in v.tau_spread]
                                 for k, v in self.cross_validation.items() if np.isfinite(v.tau_spread[0])},
            "channel_tau": {k: [float(f"{t:.4g}") for t in v] for k, v in self.channel_taus.items()},
            "per_channel_check": {
                k: {"leave_one_out_tau": [[float(f"{t:.4g}") for t in fold] for fold in v.channel_fold_tau],
                    "held_out_one_tau_db": round(v.held_out_shared_db, 3),
                    "held_out_tau_per_channel_db": round(v.held_out_channel_db, 3),
                    "gain_standard_error_db": round(v.channel_gain_se_db, 3)}
                for k, v in self.cross_validation.items() if v.channel_fold_tau},
            "scene_prior": {
                k: {**v.prior.to_json(), "tau": float(f"{v.curve.tau:.4g}"),
                    "held_out_mean_psnr_db": round(v.held_out_mean_db, 3),
                    "plain_held_out_mean_psnr_db": round(v.plain_held_out_db, 3),
                    "fold_tau": [float(f"{t:.4g}") for t in v.fold_tau]}
                for k, v in self.cross_validation.items() if v.prior is not None},
            "scene_prior_candidates": {
                k: [{"alpha": p.alpha, "k0": p.k0, "tau": float(f"{c.tau:.4g}"),
                     "held_out_mean_psnr_db": round(v.prior_held_out_db[p], 3),
                     "all_scenes_mean_psnr_db": round(max(c.values), 3)} for p, c in v.prior_curves]
                for k, v in self.cross_validation.items() if v.prior_curves},
            "curves": [c.to_json() for c in self.curves],
            **({"scene_prior_search": dict(self.prior_search)} if self.prior_search else {}),
        }

    def write_taus(self, meta: dict[str, Any]) -> None:
        """Put each decoder's τ (and τ per channel where chosen) into ``calibration.json`` fields."""
        for name, tau in self.decoder_taus.items():
            meta[tau_key(name)] = float(tau)
        meta.pop("channel_tau", None)
        if self.channel_taus:
            meta["channel_tau"] = {k: [float(t) for t in v] for k, v in self.channel_taus.items()}
        meta.pop("scene_prior", None)
        if self.priors:
            meta["scene_prior"] = {k: v.to_json() for k, v in self.priors.items()}


def validation_frames(recording: Recording, collection: SlitCollection, saturation_dn: float) -> ValidationFrames:
    """Signals (DN above dark at the reference exposure, float32) and scenes of the validation frames."""
    out = ValidationFrames([], [], [], [])
    for i in collection.validation:
        truth = recording.scene(i)
        if truth is None:
            continue
        signal, _ = signal_of(recording, i, collection.dark_dn, collection.exposure_us)
        out.labels.append(recording.frames[i].label or Path(recording.frames[i].measurement).stem)
        out.signals.append(signal.astype(np.float32))
        out.truths.append(np.asarray(truth, np.float32))
        out.saturated.append(float(np.mean(np.asarray(recording.measurement(i)) >= saturation_dn - 1.0)))
    return out


def _results(frames: ValidationFrames, estimates: list[np.ndarray]) -> list[ValidationResult]:
    out = []
    for label, est, truth, sat in zip(frames.labels, estimates, frames.truths, frames.saturated, strict=True):
        r = score(label, est, truth)
        r.saturated_fraction = sat
        out.append(r)
    return out


def _noise_curves(decoder: Any, sm: SystemMatrices, frames: ValidationFrames, noise: NoiseEstimate,
                  grid: np.ndarray) -> tuple[TauCurve, TauCurve]:
    return noise_criteria(decoder, sm, frames.signals,
                          lambda y: 1.0 / noise.variance(np.asarray(y, np.float64)), grid)


def has_noise_curves(selection: TauSelection) -> bool:
    """Whether ``selection`` holds the GCV and discrepancy curves."""
    return any(c.criterion in ("gcv", "discrepancy") for c in selection.curves)


def noise_curves_of(profile: Profile, bundle: CalibrationBundle, frames: ValidationFrames,
                    noise: NoiseEstimate, name: str, decoder: Any | None = None) -> list[TauCurve]:
    """The GCV and discrepancy curves of decoder ``name`` on ``frames`` (plain Tikhonov where
    it takes a scene prior, as :func:`select` computes them); empty without validation frames.

    ``decoder``: that decoder as :func:`select` built it (plain Tikhonov; its τ is changed),
    else it is built here."""
    if not frames.signals:
        return []
    if decoder is None:
        decoder = make_decoder(profile, bundle, name, **({"prior": None} if takes_scene_prior(name) else {}))
    sm = bundle.system_matrices
    return list(_noise_curves(decoder, sm, frames, noise, tau_grid(sm)))


def add_noise_curves(profile: Profile, bundle: CalibrationBundle, frames: ValidationFrames,
                     noise: NoiseEstimate, selection: TauSelection, decoder: Any | None = None) -> None:
    """Append the GCV and discrepancy curves of the chosen decoder to ``selection.curves``,
    for a selection made with ``noise_criteria_curves=False`` whose choice did not need them
    (cross-validation chose): the calibration computes them beside the prediction.
    Nothing is done when they are there already or there are no validation frames.

    ``decoder``: as for :func:`noise_curves_of`."""
    if not frames.signals or has_noise_curves(selection):
        return
    selection.curves += noise_curves_of(profile, bundle, frames, noise, selection.decoder, decoder)


SELECT_WORKERS = 2
"""Cross-validations :func:`select` runs at once (threads: numpy's kernels release the
interpreter lock), the calibration's two lanes."""


def _cross_validate_all(
    profile: Profile, bundle_for: Callable[[str], CalibrationBundle], frames: ValidationFrames, names: list[str],
    grid: np.ndarray, on_decoder: Callable[[str], None] | None, built: dict[str, Any] | None = None,
    narrowed: dict[str, ScenePrior | None] | None = None,
) -> tuple[dict[str, CrossValidation], dict[str, Any]]:
    """Each decoder's cross-validation (:func:`~thintact_sdk.calibration.tau.cross_validate`;
    with its scene priors, :func:`~thintact_sdk.calibration.tau.cross_validate_prior`'s
    choice), and the plain decoders built for them, by name. Each decoder is built on
    ``bundle_for(name)``, which may wait, in that decoder's own job, for a joint filter still
    being trained.

    Every build and cross-validation is one job of one pool of :data:`SELECT_WORKERS`: the
    plain decoders first, then every scene prior, so no core waits for the slowest job of one
    decoder before the next decoder starts. The results are combined in the order a
    sequential search takes them, so the choice is the same. ``built`` receives the plain
    decoders as soon as they are built (before ``on_decoder`` is called). ``narrowed``: the
    scene prior to compare with plain Tikhonov, per decoder named there (``None``: none), in
    place of every candidate.
    """
    sig, tru, lab = frames.signals, frames.truths, frames.labels
    plain_kwargs = {name: {"prior": None} if takes_scene_prior(name) else {} for name in names}
    def candidates(name: str) -> list[ScenePrior]:
        if not (takes_scene_prior(name) and enough_folds(tru)):
            return []
        if narrowed is not None and name in narrowed:
            prior = narrowed[name]
            return [] if prior is None else [prior]
        return prior_candidates()

    priors = {name: candidates(name) for name in names}

    def plain(name: str) -> tuple[Any, CrossValidation | None]:
        dec = make_decoder(profile, bundle_for(name), name, **plain_kwargs[name])
        return dec, cross_validate(dec, name, sig, tru, lab, grid)

    def with_prior(name: str, prior: ScenePrior) -> CrossValidation | None:
        return cross_validate(make_decoder(profile, bundle_for(name), name, prior=prior), name, sig, tru, lab, grid)

    with ThreadPoolExecutor(max_workers=SELECT_WORKERS, thread_name_prefix="select-cv") as pool:
        jobs = {name: pool.submit(plain, name) for name in names}
        prior_jobs = {name: [pool.submit(with_prior, name, p) for p in priors[name]] for name in names}
        try:
            decoders: dict[str, Any] = {}
            plain_cvs: dict[str, CrossValidation] = {}
            for name in names:
                decoders[name], cv = jobs[name].result()
                if cv is not None:
                    plain_cvs[name] = cv
            if built is not None:
                built.update(decoders)
            if on_decoder is not None and plain_cvs:
                # only the leader's own priors can still move the scores: then it stays ahead
                leader = max(plain_cvs.values(), key=lambda cv: cv.held_out_mean_db).decoder
                if priors[leader] and not any(priors[n] for n in plain_cvs if n != leader):
                    on_decoder(leader)
            cvs: dict[str, CrossValidation] = {}
            for name, cv in plain_cvs.items():
                cvs[name] = cv if not priors[name] else choose_prior(
                    cv, priors[name], [f.result() for f in prior_jobs[name]], lab, tru)
        except BaseException:
            for job in jobs.values():
                job.cancel()
            for fs in prior_jobs.values():
                for f in fs:
                    f.cancel()
            raise
    return cvs, decoders


def select(
    profile: Profile,
    bundle: CalibrationBundle,
    frames: ValidationFrames,
    noise: NoiseEstimate | Callable[[], NoiseEstimate],
    *,
    decoder: str | None = None,
    tau: float | None = None,
    simulated: TauCurve | Callable[[], TauCurve | None] | None = None,
    noise_criteria_curves: bool = True,
    built: dict[str, Any] | None = None,
    on_decoder: Callable[[str], None] | None = None,
    filtered: Callable[[], CalibrationBundle] | None = None,
    design_priors: dict[str, ScenePrior | None] | None = None,
) -> TauSelection:
    """Choose the decoder and τ on the unit's validation frames.

    Parameters
    ----------
    profile
        The device profile.
    bundle
        The unit's bundle (matrices and trained filter; without a filter when ``filtered`` is
        given).
    frames
        Its validation frames.
    noise
        The noise measured on its slit frames (weights of GCV and the discrepancy principle),
        or a function giving it, called only when those are computed (e.g. a measurement
        still running when the choice starts).
    decoder
        Impose this decoder (default: the best of
        :func:`~thintact_sdk.calibration.validation.calibration_decoders`).
    tau
        Impose this τ (no selection; the validation is then scored at it).
    simulated
        The τ curve on simulated training scenes (reported, and the fallback), or a function
        giving it (called once the decoders are cross-validated).
    noise_criteria_curves
        Compute the GCV and discrepancy curves (reported; GCV is the fallback without a
        simulated curve).
    built
        Filled with the decoders built for the choice, by name (plain Tikhonov where a
        decoder takes a scene prior), for :func:`add_noise_curves` to take instead of
        building the chosen one again.
    on_decoder
        Called with the chosen decoder's name as soon as it is certain while the scene
        priors are still being cross-validated: when plain Tikhonov of the one decoder that
        takes scene priors already scores best (a prior only replaces plain Tikhonov by
        scoring higher). Not called otherwise; the decoders in ``built`` are complete by then, and the
        chosen one's is no longer used by the choice (the calibration starts the work that
        depends on the name alone, e.g. its noise criteria and prediction).
    filtered
        A function giving the bundle with its trained joint filter, for the decoders that
        need one (:func:`~thintact_sdk.calibration.validation.needs_joint_filter`): they are
        built on it, in their own jobs, so the decoders that need no filter are
        cross-validated while it is still being trained. Without it, every decoder is built
        on ``bundle``.
    design_priors
        Per decoder, the scene prior chosen on the design's own validation frames during the
        capture (:func:`~thintact_sdk.calibration.capture_worker.design_priors`; ``None``:
        plain Tikhonov): that decoder compares plain Tikhonov with this prior alone instead
        of every candidate, and deploys it only where it wins on the unit's frames too. The
        selection's ``prior_search`` says which search was made.
    """
    sm = bundle.system_matrices

    def bundle_for(name: str) -> CalibrationBundle:
        return filtered() if filtered is not None and needs_joint_filter(name) else bundle

    def simulated_curve() -> list[TauCurve]:
        curve = simulated() if callable(simulated) else simulated
        return [] if curve is None else [curve]

    def measured_noise() -> NoiseEstimate:
        return noise() if callable(noise) else noise

    names = [decoder] if decoder else calibration_decoders()
    if tau is not None:
        name = names[0] if decoder else default_decoder()
        dec = make_decoder(profile, bundle_for(name), name, tau=tau)
        estimates = [np.asarray(dec.decode(y), np.float32) for y in frames.signals]
        return TauSelection(name, float(tau), "given (--tau)", {name: float(tau)}, simulated_curve(),
                            validation=_results(frames, estimates))
    grid = tau_grid(sm)
    cvs, decoders = _cross_validate_all(profile, bundle_for, frames, names, grid, on_decoder, built, design_priors)
    curves = simulated_curve()
    fallback = curves[0] if curves else None
    for name, cv in cvs.items():
        what = "" if cv.prior is None else f", scene prior alpha {cv.prior.alpha:g} k0 {cv.prior.k0:g}"
        curves.append(TauCurve(f"cross-validation ({name}{what})", cv.curve.taus, cv.curve.values,
                               cv.curve.tau, cv.curve.unit, cv.curve.note))
    if cvs:
        best = max(cvs.values(), key=lambda cv: cv.held_out_mean_db)
        chosen, criterion, tau_chosen = best.decoder, "cross-validation", best.curve.tau
    else:
        chosen = names[0] if decoder else default_decoder()
        criterion, tau_chosen = "gcv", float("nan")
    if frames.signals and (noise_criteria_curves or (not cvs and fallback is None)):
        gcv, discrepancy = _noise_curves(decoders[chosen], sm, frames, measured_noise(), grid)
        curves += [gcv, discrepancy]
        tau_chosen = gcv.tau if not cvs else tau_chosen
    if not cvs and fallback is not None:
        # GCV under-regularises on these frames (docs/calibration.md): without two folds of
        # scenes the simulated-scene choice is the safer default; GCV stays in the report.
        criterion, tau_chosen = "simulated", fallback.tau
    decoder_taus = {name: cv.curve.tau for name, cv in cvs.items()} or {chosen: tau_chosen}
    selection = TauSelection(chosen, tau_chosen, criterion, decoder_taus, curves, cvs)
    if design_priors:
        selection.prior_search = {
            name: "chosen on the design's simulated validation frames during the capture: "
            + ("none (plain Tikhonov)" if p is None else f"alpha {p.alpha:g}, k0 {p.k0:g}")
            + "; the unit compared plain Tikhonov with it alone"
            for name, p in design_priors.items()}
    if chosen in cvs:
        cv = cvs[chosen]
        selection.validation = _results(frames, [cv.held_out_estimates[lb] for lb in frames.labels])
        if cv.plain is not None:
            selection.judged_validation = _results(
                frames, [cv.plain.held_out_estimates[lb] for lb in frames.labels])
    else:
        dec = decoders[chosen]
        dec.set_tau(tau_chosen)  # type: ignore[attr-defined]
        selection.validation = _results(frames, [np.asarray(dec.decode(y), np.float32) for y in frames.signals])
    return selection
