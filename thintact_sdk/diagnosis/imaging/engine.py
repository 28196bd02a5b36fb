"""The diagnosis pipeline: baseline → locate → name and fit effects → unexplained structure."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from thintact_sdk.diagnosis.core.report_sections import (
    diagnosis_report,
    finding_entry,
    fit_section,
    unexplained_section,
)
from thintact_sdk.diagnosis.imaging.candidates import CANDIDATES
from thintact_sdk.diagnosis.imaging.coarse_angle import EFFECT as ANGLE_EFFECT
from thintact_sdk.diagnosis.imaging.coarse_angle import (
    CoarseAngle,
    CoarseAngleInput,
    coarse_angle_stage,
)
from thintact_sdk.diagnosis.imaging.deadline import Deadline
from thintact_sdk.diagnosis.imaging.forward_model import (
    DiagnosisModel,
    Evaluation,
    SimulateFn,
    Values,
    contract_fit,
    default_simulate,
    evaluate_self_weighted,
)
from thintact_sdk.diagnosis.imaging.locate import Location, locate
from thintact_sdk.diagnosis.imaging.recording_data import DiagnosisData, subset_frames
from thintact_sdk.diagnosis.imaging.select import FineAmplitude, Round, Selection, select_effects
from thintact_sdk.diagnosis.imaging.stats import (
    FitStats,
    VarianceFn,
    default_variance_fn,
    normalised_residual,
)
from thintact_sdk.diagnosis.imaging.structure import Structure, find_structure
from thintact_sdk.diagnosis.imaging.unbinned import UnbinnedInput, UnbinnedStage, unbinned_stage
from thintact_sdk.diagnosis.imaging.words import describe_effect, tell_apart
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.host.blas import blas_threads
from thintact_sdk.simulation.effects import EFFECTS


@dataclass
class DiagnoseOptions:
    """Knobs of :func:`diagnose` (defaults are the CLI's).

    Attributes
    ----------
    sys_frac
        Systematic-error allowance (relative model error) used in fitting and decisions.
    margin
        Δχ² added to the BIC penalty k·ln(n) before an effect is accepted.
    amp_floor
        Minimum rms change of the prediction (fraction of the rms signal) for an effect.
    max_effects
        At most this many effects are accepted.
    time_budget_s
        Wall-clock budget; selection stops when it is spent.
    candidates
        Effect names to consider (default: every CONTRACTS §5 effect the simulator knows,
        minus those the profile already models).
    blas_threads
        OpenBLAS threads while diagnosing (1 is fastest on a busy machine; None leaves
        numpy's setting).
    fit_frames
        Effects are named and fitted on at most this many frames spread over the
        recording (the simulator's cost grows with frames); every frame is evaluated.
    held_params
        ``{effect: parameter labels}`` held at their null value (not screened): what the
        simulator cannot build on this device within the diagnosis's memory, e.g. a rotated
        mask's ``angle_deg`` at the paper's size (:func:`~thintact_sdk.diagnosis.imaging.binning.screening_limits`);
        the effect's other parameters are screened and fitted, and an effect with every
        parameter held is not tried.
    fine_amplitude
        For binned data: the effect's change of the prediction measured on the unbinned
        recording (:func:`~thintact_sdk.diagnosis.imaging.binning.unbinned_amplitude_fn`), which
        an effect whose binned change is under ``amp_floor`` may reach instead
        (:func:`~thintact_sdk.diagnosis.imaging.select.select_effects`).
    unbinned
        For binned data: the unbinned recording, on whose frames the accepted model is
        checked and, where its χ² is in excess, effects finer than a block are selected
        (:mod:`~thintact_sdk.diagnosis.imaging.unbinned`).
    coarse_angle
        For binned data whose mask angle is held: the unbinned recording, from which the
        angle is fitted on coarser blocks after the selection
        (:mod:`~thintact_sdk.diagnosis.imaging.coarse_angle`).
    """

    sys_frac: float = 1e-3
    margin: float = 25.0
    amp_floor: float = 6e-4
    max_effects: int = 4
    time_budget_s: float = 75.0
    candidates: list[str] | None = None
    fit_frames: int = 12
    blas_threads: int | None = 1
    held_params: dict[str, tuple[str, ...]] = field(default_factory=dict)
    fine_amplitude: FineAmplitude | None = None
    unbinned: UnbinnedInput | None = None
    coarse_angle: CoarseAngleInput | None = None


@dataclass
class ModelView:
    """A prediction with its contract statistics, for the report and the figures."""

    pred_dn: np.ndarray
    variance_dn2: np.ndarray
    valid: np.ndarray
    stats: FitStats


@dataclass
class Diagnosis:
    """Everything :func:`diagnose` found (``report`` is CONTRACTS §6 ``report.json``)."""

    data: DiagnosisData
    report: dict[str, Any]
    fitted_profile: Profile
    baseline_pred_dn: np.ndarray
    final_pred_dn: np.ndarray
    baseline_location: Location
    final_location: Location
    structure: Structure
    selection: Selection
    history: list[tuple[str, float, float]]  # (model, rms_dn, chi2_per_dof)
    timing_s: dict[str, float] = field(default_factory=dict)
    unbinned: UnbinnedStage | None = None  # the unbinned stage of a binned diagnosis
    unbinned_skipped: str = ""  # why the unbinned stage could not run (a refused full-size kernel)
    coarse_angle: CoarseAngle | None = None  # the held angle fitted on coarser blocks


def known_candidates(profile: Profile) -> list[str]:
    """Effects the diagnosis can try: every registered effect that declares a fit, minus
    those already in the profile's physics."""
    return [n for n in CANDIDATES if n not in profile.physics]


def held_indices(held_params: dict[str, tuple[str, ...]]) -> dict[str, tuple[int, ...]]:
    """``{effect: labels}`` → ``{effect: indices into its fit vector}`` (unknown effects
    are ignored; an unknown label is a :class:`~thintact_sdk.errors.ThinTactError`)."""
    out: dict[str, tuple[int, ...]] = {}
    for name, labels in held_params.items():
        if name not in CANDIDATES:
            continue
        known = CANDIDATES[name].labels
        bad = [lab for lab in labels if lab not in known]
        if bad:
            raise ThinTactError(f"held parameters {bad} are not fit parameters of {name} {known}")
        out[name] = tuple(known.index(lab) for lab in labels)
    return out


def contract_params(name: str, vec: np.ndarray, model: DiagnosisModel, beta: np.ndarray,
                    values: Values) -> dict[str, Any]:
    """Contract parameters of an accepted effect; a linear-domain effect's come from its
    coefficients in the final closed-form fit (``beta``, with every effect of ``values``)."""
    cand = CANDIDATES[name]
    if cand.domain != "linear" or cand.fit.report is None:
        return cand.to_params(vec, model.profile)
    coef = beta[:, model.linear_slices(values)[name]]
    return cand.fit.report(coef, model.basis(name), model.profile)


def profile_params(name: str, params: dict[str, Any]) -> dict[str, Any]:
    """Only the parameters the simulator's effect accepts (for ``fitted_profile.json``)."""
    spec = EFFECTS.get(name)
    if spec is None:
        return params
    out: dict[str, Any] = {}
    for k, v in params.items():
        if k in spec.params:
            lo, hi = spec.params[k].bounds
            out[k] = np.clip(np.asarray(v, float), lo, hi).tolist()
    return out


def _view(model: DiagnosisModel, pred: np.ndarray, values: Values) -> ModelView:
    return ModelView(pred, *contract_fit(model, pred, values))


def _locate(view: ModelView, data: DiagnosisData, black: float) -> Location:
    resid = data.measured_dn - view.pred_dn
    z = normalised_residual(data.measured_dn, view.pred_dn, view.variance_dn2, view.valid)
    return locate(
        z, view.valid, view.pred_dn - black, resid, view.variance_dn2,
        data.profile.sensor.pixel_pitch_um, data.labels, list(data.profile.sensor.channels),
    )


def _structure(view: ModelView, data: DiagnosisData, black: float) -> Structure:
    resid = data.measured_dn - view.pred_dn
    z = normalised_residual(data.measured_dn, view.pred_dn, view.variance_dn2, view.valid)
    return find_structure(resid, view.pred_dn - black, view.variance_dn2, view.valid, z)


def _frame_hint(data: DiagnosisData, model: DiagnosisModel, a: Evaluation, b: Evaluation) -> str:
    d = (a.pred_dn - b.pred_dn) ** 2 * model.weights
    per = np.sqrt(d.mean(axis=(1, 2, 3)))
    i = int(np.argmax(per))
    rms = float(np.sqrt(np.mean((a.pred_dn[i] - b.pred_dn[i]) ** 2)))
    return (
        f"in this recording their predictions differ most on frame '{data.labels[i]}' "
        f"({rms:.2f} DN rms), so more frames like it would help."
    )


def diagnose(
    data: DiagnosisData,
    simulate: SimulateFn | None = None,
    variance_fn: VarianceFn | None = None,
    options: DiagnoseOptions | None = None,
    progress: Callable[[str], None] | None = None,
) -> Diagnosis:
    """Diagnose a recording (CONTRACTS §6): see the package docstring."""
    opt = options or DiagnoseOptions()
    with blas_threads(opt.blas_threads):
        return _diagnose(data, simulate, variance_fn, opt, progress)


def _diagnose(
    data: DiagnosisData,
    simulate: SimulateFn | None,
    variance_fn: VarianceFn | None,
    opt: DiagnoseOptions,
    progress: Callable[[str], None] | None,
) -> Diagnosis:
    t_start = time.perf_counter()
    deadline = Deadline.after(opt.time_budget_s)
    say = progress or (lambda _m: None)
    sim = simulate or default_simulate
    var_fn = variance_fn or default_variance_fn()
    prof = data.profile
    black = float(prof.noise.black_level_dn)
    model = DiagnosisModel(data, sim, var_fn, sys_frac=opt.sys_frac)
    base_values: Values = {
        n: CANDIDATES[n].from_params(prof.physics[n], prof)
        for n in prof.physics
        if n in CANDIDATES and CANDIDATES[n].domain != "optical"
    }
    held = held_indices(opt.held_params)
    cands = [c for c in (opt.candidates if opt.candidates is not None else known_candidates(prof))
             if len(held.get(c, ())) < CANDIDATES[c].k]
    timing: dict[str, float] = {}

    ev0 = evaluate_self_weighted(model, base_values)
    base = _view(model, ev0.pred_dn, base_values)
    loc0 = _locate(base, data, black)
    timing["baseline_s"] = time.perf_counter() - t_start
    say(f"baseline: rms {base.stats.rms_dn:.2f} DN, χ²/dof {base.stats.chi2_per_dof:.3f}")

    sub = subset_frames(data, opt.fit_frames)
    fit_model = DiagnosisModel(sub, sim, var_fn, sys_frac=opt.sys_frac, held=held)
    sel = select_effects(
        fit_model, cands, base_values, max_effects=opt.max_effects, margin=opt.margin,
        amp_floor=opt.amp_floor, deadline=deadline, progress=say,
        fine_amplitude=opt.fine_amplitude,
    )
    ev1 = evaluate_self_weighted(model, sel.values)
    final = _view(model, ev1.pred_dn, sel.values)
    struct = _structure(final, data, black)
    if struct.significant and deadline.remaining_s() > 0.25 * opt.time_budget_s:
        # a local defect biases the effect fits: fit again without its pixels
        say("local defect found: refitting the effects without it")
        fit2 = DiagnosisModel(sub, sim, var_fn, sys_frac=opt.sys_frac, exclude=struct.mask,
                              held=held)
        fit2.cache = fit_model.cache
        sel = select_effects(
            fit2, cands, base_values, max_effects=opt.max_effects, margin=opt.margin,
            amp_floor=opt.amp_floor, deadline=deadline, progress=say,
            fine_amplitude=opt.fine_amplitude,
        )
        fit_model = fit2
        ev1 = evaluate_self_weighted(model, sel.values)
        final = _view(model, ev1.pred_dn, sel.values)
        struct = _structure(final, data, black)
    timing["selection_s"] = time.perf_counter() - t_start - timing["baseline_s"]
    coarse: CoarseAngle | None = None
    if opt.coarse_angle is not None and "angle_deg" in opt.held_params.get(ANGLE_EFFECT, ()) \
            and ANGLE_EFFECT in cands:
        t_stage = time.perf_counter()
        coarse, angled = coarse_angle_stage(opt.coarse_angle, sel.values, [r.name for r in sel.rounds],
                                            sys_frac=opt.sys_frac,
                                            margin=opt.margin, amp_floor=opt.amp_floor, progress=say)
        if coarse.accepted:
            say("evaluating the fitted angle on the diagnosis's binned data")
            sel = _with_coarse_angle(sel, angled, coarse, fit_model, opt)
            if coarse.accepted:
                ev1 = evaluate_self_weighted(model, sel.values)
                final = _view(model, ev1.pred_dn, sel.values)
                struct = _structure(final, data, black)
        timing["coarse_angle_s"] = time.perf_counter() - t_stage
    stage: UnbinnedStage | None = None
    unbinned_skipped = ""
    fine_names: set[str] = set()
    binned_sel = sel
    if opt.unbinned is not None:
        t_stage = time.perf_counter()
        say("checking the fit on unbinned frames")
        try:
            stage = unbinned_stage(opt.unbinned, sel.values, cands, sys_frac=opt.sys_frac,
                                   max_effects=opt.max_effects - len(sel.rounds), margin=opt.margin,
                                   amp_floor=opt.amp_floor, held=held, progress=say)
        except ThinTactError as err:  # the full-size kernel of the fitted model is refused (its size)
            unbinned_skipped = str(err)
            say(f"unbinned frames not evaluated: {err}")
    if stage is not None:
        fine = stage.selection
        if fine is not None or stage.replaced:
            rounds = [_replaced_round(r, stage, opt.margin) if r.name in stage.replaced else r for r in sel.rounds]
            for rnd in rounds:  # refitted at full size (and by the joint refits there)
                rnd.vector = stage.values.get(rnd.name, rnd.vector)
            fine_names = {r.name for r in fine.rounds} if fine is not None else set()
            fine_names |= {a.name for a in stage.replaced.values()}
            sel = Selection(stage.values, rounds + (fine.rounds if fine is not None else []), sel.evaluation,
                            sel.rejected + (fine.rejected if fine is not None else []),
                            sel.log + (fine.log if fine is not None else []), sel.below_floor)
            ev1 = evaluate_self_weighted(model, sel.values)
            final = _view(model, ev1.pred_dn, sel.values)
            struct = _structure(final, data, black)
    if opt.unbinned is not None:
        timing["unbinned_s"] = time.perf_counter() - t_stage
    loc1 = _locate(final, data, black)

    history = [("baseline", base.stats.rms_dn, base.stats.chi2_per_dof)]
    findings = []
    phys = dict(prof.physics)
    accepted: Values = dict(base_values)
    # findings describe the device itself (its pixels), not the binned copy the fit ran on
    device = opt.unbinned.data.profile if opt.unbinned is not None else prof
    for i, rnd in enumerate(sel.rounds):
        accepted[rnd.name] = rnd.vector
        if i == len(sel.rounds) - 1:
            view = final
        else:
            ev_r = evaluate_self_weighted(model, accepted)
            view = _view(model, ev_r.pred_dn, accepted)
        replaced = next((old for old, a in stage.replaced.items() if a.name == rnd.name), None) \
            if stage is not None else None
        if rnd.name in fine_names and stage is not None and stage.model is not None and stage.data is not None:
            findings.append(_finding(rnd, stage.model, stage.data, device, view, ev1.beta, sel.values))
            if replaced is not None:
                a = stage.replaced[replaced]
                findings[-1]["evidence"] += (
                    f" Named on {stage.data.n_frames} unbinned frames in place of {replaced}, which the "
                    f"binned data preferred (binning only approximates {rnd.name}): there it lowers χ² by "
                    f"{a.dchi2:.0f} against {a.own_dchi2:.0f}, beyond the {a.tol:.0f} within which the two "
                    "would be alternatives.")
            else:
                findings[-1]["evidence"] += (
                    f" Named on {stage.data.n_frames} unbinned frames: binned {_stage_bin(opt)}×{_stage_bin(opt)} "
                    f"its signature averages out inside a block, while there the fit without it left χ² "
                    f"{stage.excess_z:.1f} standard deviations above the noise.")
        else:
            findings.append(_finding(rnd, fit_model, sub, device, view, ev1.beta, sel.values))
            if stage is not None and stage.data is not None and rnd.name in stage.refitted:
                findings[-1]["evidence"] += (
                    f" Its parameters were refitted on {stage.data.n_frames} unbinned frames (binning "
                    "only approximates an effect after the imaging kernel).")
        if stage is not None and stage.data is not None:
            for alt in stage.alternatives.get(rnd.name, []):
                if alt.name in findings[-1]["alternatives"]:
                    continue
                findings[-1]["alternatives"].append(alt.name)
                params = CANDIDATES[alt.name].to_params(alt.vector, device)
                findings[-1]["evidence"] += (
                    f" On {stage.data.n_frames} unbinned frames {alt.name} {params} explains the recording "
                    f"about as well in its place (Δχ² {alt.dchi2:.0f} against {alt.own_dchi2:.0f}). "
                    + tell_apart(rnd.name, alt.name, "frames that would tell them apart are not in this recording."))
        held_here = [p for p in opt.held_params.get(rnd.name, ())
                     if not (coarse is not None and coarse.ran and rnd.name == ANGLE_EFFECT and p == "angle_deg")]
        if coarse is not None and coarse.ran and rnd.name == ANGLE_EFFECT:
            findings[-1]["evidence"] += coarse.evidence(_binned_factor(opt)) if coarse.accepted \
                else coarse.screened_evidence()
        if held_here:
            findings[-1]["evidence"] += (
                f" Its {', '.join(held_here)} was held at the null value: "
                "not screened on this device (the kernels would not fit in memory).")
        _name_unscreened_stand_ins(findings[-1], rnd, held, device)
        history.append((f"+ {rnd.name}", view.stats.rms_dn, view.stats.chi2_per_dof))
        phys[rnd.name] = profile_params(rnd.name, findings[-1]["params"])
    fitted = prof.with_physics(phys)
    report = diagnosis_report(
        noise_rms_dn=round(base.stats.noise_rms_dn, 4),
        baseline=fit_section(round(base.stats.rms_dn, 4), round(base.stats.chi2_per_dof, 4)),
        located={"summary": loc0.summary, "hotspots": [h.to_json() for h in loc0.hotspots]},
        findings=findings,
        final=fit_section(round(final.stats.rms_dn, 4), round(final.stats.chi2_per_dof, 4)),
        unexplained=unexplained_section(struct.significant, struct.summary,
                                        [h.to_json() for h in struct.hotspots]),
    )
    low = _below_floor_json(binned_sel, stage, sel.values, device, opt)
    if low:  # beyond CONTRACTS §6, only when there is something to say
        report["below_floor"] = low
    timing["total_s"] = time.perf_counter() - t_start
    timing["simulations"] = float(model.n_sim + fit_model.n_sim)
    return Diagnosis(
        data, report, fitted, ev0.pred_dn, ev1.pred_dn, loc0, loc1, struct, sel, history, timing, stage,
        unbinned_skipped, coarse,
    )


def _name_unscreened_stand_ins(finding: dict[str, Any], rnd: Round, held: dict[str, tuple[int, ...]],
                               device: Profile) -> None:
    """Name, among ``finding``'s alternatives, each effect the diagnosis could not screen on
    this device (every fit parameter held: ``not_screened`` in report.json, under ``binned`` when binned) for which this finding
    is a plausible stand-in (its :class:`~thintact_sdk.simulation.effects.Proxy` points at it from here,
    e.g. a much shorter scene gap at the paper's size, where refraction is out of reach: near
    the axis the two look alike). The recording was never compared with it, so the evidence
    says what it would take. ``held``: the held fit parameters' indices per effect."""
    for name, cand in CANDIDATES.items():
        px = cand.proxy
        if (px is None or px.source != rnd.name or px.stand_in is None or name in finding["alternatives"]
                or len(held.get(name, ())) < cand.k):
            continue
        start = px.start(np.asarray(rnd.vector, float), device)
        if start is None or not px.stand_in(start):
            continue
        finding["alternatives"].append(name)
        params = cand.to_params(start, device)
        finding["evidence"] += (
            f" {name} was not screened on this device (its kernel is out of reach at this size, "
            f"report.json not_screened), and near the axis {name} {params} would look the "
            "same as this finding: the recording cannot tell them apart here. "
            + tell_apart(rnd.name, name, f"on this device only a measured gap would, {name} being out of reach here."))


def _below_floor_json(binned: Selection, stage: UnbinnedStage | None, accepted: Values, device: Profile,
                      opt: DiagnoseOptions) -> list[dict[str, Any]]:
    """``report.json`` ``below_floor``: effects the data show (their fit cleared the Δχ²
    criterion) but whose change of the prediction stayed under the amplitude floor, so none
    is named; with where that was measured (the fit's data, or the unbinned stage's frames)."""
    where = "fit data" if opt.unbinned is None else f"binned {opt.unbinned.bin_factor}×{opt.unbinned.bin_factor}"
    out: list[dict[str, Any]] = []
    seen: set[str] = set()
    for b in binned.below_floor:
        if b.name not in accepted:
            out.append({**b.to_json(device), "data": where, "floor": opt.amp_floor})
            seen.add(b.name)
    if stage is not None and stage.data is not None:
        for b in stage.below_floor():
            if b.name not in accepted and b.name not in seen:
                out.append({**b.to_json(device), "data": f"{stage.data.n_frames} unbinned frames",
                            "floor": opt.amp_floor})
    return out


def _replaced_round(rnd: Round, stage: UnbinnedStage, margin: float) -> Round:
    """The round of the rival that took ``rnd``'s place on the unbinned frames."""
    a = stage.replaced[rnd.name]
    k = CANDIDATES[a.name].k
    n = stage.model.n_fit if stage.model is not None else 2
    return Round(a.name, a.vector, a.dchi2, k * float(np.log(max(n, 2))) + margin, k, a.amplitude_dn,
                 [], [], rnd.evaluation)


def _with_coarse_angle(sel: Selection, angled: Values, coarse: CoarseAngle, fit_model: DiagnosisModel,
                       opt: DiagnoseOptions) -> Selection:
    """The selection with what the coarse stage accepted (the angle; effects it found to
    stand in for the rotation dropped), evaluated on the fit's binned data. The mask's
    finding gets the drop-one Δχ² there (the model without the effect against the model
    with it) and counts its shift's parameters only when the shift was kept. Left unchanged
    when that data does not confirm the change, or when every effect slot is taken."""
    before = fit_model.evaluate(sel.values)
    after = fit_model.evaluate(angled)
    coarse.confirmed_dchi2 = before.chi2 - after.chi2
    ln_n = float(np.log(max(fit_model.n_fit, 2)))
    kept = [r for r in sel.rounds if r.name in angled]
    own = next((r for r in kept if r.name == ANGLE_EFFECT), None)
    if coarse.confirmed_dchi2 <= ln_n or (own is None and len(kept) >= opt.max_effects):
        coarse.accepted = False
        coarse.note += (f" Not named: on the diagnosis's binned data it lowers χ² by {coarse.confirmed_dchi2:.0f}."
                        if coarse.confirmed_dchi2 <= ln_n else
                        f" Not named: all {opt.max_effects} effect slots are taken.")
        return sel
    vec = np.asarray(angled[ANGLE_EFFECT], float)
    without = fit_model.evaluate({n: v for n, v in angled.items() if n != ANGLE_EFFECT})
    d = (after.pred_dn - without.pred_dn)[fit_model.fit_mask]
    amp = float(np.sqrt(np.mean(d * d))) if d.size else 0.0
    k = 1 + (len(vec) - 1 if np.any(vec[1:]) else 0)
    rnd = Round(ANGLE_EFFECT, vec, without.chi2 - after.chi2, k * ln_n + opt.margin, k, amp, [], [], after)
    rounds = [rnd if r is own else r for r in kept] if own is not None else [*kept, rnd]
    return Selection(angled, rounds, after, sel.rejected, [*sel.log, coarse.summary()], sel.below_floor)


def _binned_factor(opt: DiagnoseOptions) -> int:
    """The block side of the diagnosis's binned data (1 when unbinned)."""
    for spec in (opt.unbinned, opt.coarse_angle):
        if spec is not None:
            return spec.bin_factor
    return 1


def _stage_bin(opt: DiagnoseOptions) -> int:
    """The block side of a binned diagnosis (1 without an unbinned stage)."""
    return 1 if opt.unbinned is None else opt.unbinned.bin_factor


def _finding(
    rnd: Round,
    model: DiagnosisModel,
    data: DiagnosisData,
    prof: Profile,
    view: ModelView,
    final_beta: np.ndarray,
    final_values: Values,
) -> dict[str, Any]:
    """One ``findings`` entry; ``view`` is the whole recording with effects up to ``rnd``;
    closed-form terms (linear-domain effects) are reported from the final fit
    (``final_beta`` with ``final_values``), where every accepted effect is in the model."""
    params = contract_params(rnd.name, rnd.vector, model, final_beta, final_values)
    ev_txt = (
        f"{describe_effect(rnd.name, params, prof)} Adding it lowers χ² by {rnd.dchi2:.0f} "
        f"(with a {model.sys_frac:.1%} systematic allowance), above the {rnd.threshold:.0f} that "
        f"{rnd.k} parameter(s) must earn (BIC k·ln n + margin); it changes the prediction by "
        f"{rnd.amplitude_dn:.2f} DN rms"
        + ("." if rnd.fine_amplitude is None else
           f" ({rnd.fine_amplitude:.1e} of the signal on the unbinned recording).")
    )
    extra: dict[str, Any] = {}
    if rnd.below_floor is not None:
        halves = [CANDIDATES[rnd.name].to_params(h, prof) for h in rnd.halves or []]
        ev_txt += (
            f" That change is {rnd.below_floor:.1e} of the rms signal, under the amplitude floor, "
            "but the fit is decisive and stable under refit: on each half of the frames it clears "
            f"the criterion again, at {' and '.join(map(str, halves))}, so it is named.")
        extra["amplitude_fraction"] = float(f"{rnd.below_floor:.3g}")
        extra["refit_on_halves"] = halves
    if rnd.swapped_from is not None:
        ev_txt += (
            f" Its round first accepted {rnd.swapped_from}; once the later effects were in, "
            f"{rnd.name} in its place fits better (BIC lower by {rnd.swap_dchi2:.0f}), so it was swapped.")
        extra["swapped_from"] = rnd.swapped_from
    for name, vec, gain in rnd.absorbed:
        ev_txt += (
            f" It makes {name} (accepted in an earlier round) unnecessary: refitted with it, that "
            f"effect went to {CANDIDATES[name].to_params(vec, prof)}, and the model without it "
            f"fits better (BIC lower by {gain:.0f}), so it was dropped.")
    if rnd.absorbed:
        extra["absorbed"] = [name for name, _v, _g in rnd.absorbed]
    alts = []
    for a in rnd.alternatives:
        assert a.evaluation is not None
        alts.append(a.name)
        ev_txt += (
            f" {a.name} explains the recording about as well (Δχ² {a.dchi2:.0f}). "
            + tell_apart(rnd.name, a.name, _frame_hint(data, model, rnd.evaluation, a.evaluation))
        )
    return finding_entry(rnd.name, params, round(view.stats.rms_dn, 4),
                         round(view.stats.chi2_per_dof, 4), ev_txt, alts, **extra)
