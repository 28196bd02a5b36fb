"""The tactile-simulation diagnosis: baseline, locate, name effects by BIC, fit, report.

1. Nuisances from the images alone (press circle, cap depth); per-pixel noise σ from
   repeat frames (:mod:`.data`).
2. Baseline: the SDK's tactile simulation of the same presses (Phong, 10-LED layout,
   σ_e = 0.25 mm) with one gain per channel (a nuisance, never a finding).
3. Greedy forward selection over the vocabulary (:mod:`.vocabulary`), the loop and BIC
   criterion imaging shares (:mod:`~thintact_sdk.diagnosis.core.forward_selection`): every
   effect not yet in the model is added and fitted; the one with the lowest BIC is accepted
   when it lowers BIC by more than ``min_delta_bic`` and explains at least
   ``min_excess_share`` of the excess χ²/dof left (χ²/dof − 1). After an effect is accepted, the press nuisances are refitted under the new model, but only once the
   model carries fitted lights (``led_directions``): the baseline's light layout belongs to
   another sensor, and fitting press positions to it moves them away from the true ones.
4. An effect that was significant in one round and no longer is once another was accepted is
   named as that finding's alternative (the data cannot tell them apart).
5. What is left is located again; structure above ``unexplained_chi2`` is flagged; the
   report is the shared skeleton (:mod:`~thintact_sdk.diagnosis.core.report_sections`) with
   the tactile keys around it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from thintact_sdk.diagnosis.core.forward_selection import InformationCriterion, forward_select
from thintact_sdk.diagnosis.core.report_sections import (
    diagnosis_report,
    finding_entry,
    fit_section,
    unexplained_section,
)
from thintact_sdk.diagnosis.tactile.fit import (
    PressData,
    Score,
    all_normals,
    clipped_mask,
    fit_linear,
    fit_presses,
    score,
    variance,
)
from thintact_sdk.diagnosis.tactile.press_data import estimate_noise, initial_presses
from thintact_sdk.diagnosis.tactile.press_model import Normals, Press, TactileModel
from thintact_sdk.diagnosis.tactile.press_residuals import TactileLocation, locate_residual
from thintact_sdk.diagnosis.tactile.vocabulary import DEFAULT_EFFECTS, PROPOSERS, effect_params
from thintact_sdk.tactile.learning.domains import RealPresses


@dataclass
class TactileDiagnosisOptions:
    """Acceptance rules of the diagnosis."""

    max_effects: int = 8
    min_delta_bic: float = 10.0
    min_excess_share: float = 0.02
    unexplained_chi2: float = 1.5
    effects: tuple[str, ...] = DEFAULT_EFFECTS


@dataclass
class TactileDiagnosis:
    """Everything the diagnosis found (``report`` is ``report.json``)."""

    report: dict[str, Any]
    data: PressData
    presses: list[Press]
    baseline: TactileModel
    final: TactileModel
    baseline_pred: np.ndarray
    final_pred: np.ndarray
    baseline_location: TactileLocation
    final_location: TactileLocation
    indices: list[int] = field(default_factory=list)


def _stats_json(s: Score) -> dict[str, float]:
    return fit_section(round(s.stats.rms_dn * 255, 4), round(s.chi2_per_dof, 5), bic=round(s.bic, 1))


def _fit_with_presses(m: TactileModel, data: PressData, presses: list[Press], passes: int = 1
                      ) -> tuple[TactileModel, list[Press], list[Normals]]:
    for _ in range(passes):
        presses = fit_presses(m, data, presses)
        nrm = all_normals(data, presses, m.sigma_mm, m.skirt_mm)
        m = fit_linear(m, data, nrm, iterations=5)
    return m, presses, nrm


@dataclass
class _Tried:
    """One effect added and fitted in a round: ``dchi2`` and ``k`` against the current model
    (so that ``dchi2 − k·ln n`` is the BIC drop)."""

    name: str
    dchi2: float
    k: int
    score: Score
    model: TactileModel
    normals: list[Normals]


class _TactileSearch:
    """The tactile side of :func:`~thintact_sdk.diagnosis.core.forward_selection.forward_select`
    (module docstring, steps 3-4): every effect of the vocabulary not yet in the model is
    added and fitted; the excess-share rule admits; alternatives are named a round late."""

    def __init__(self, data: PressData, presses: list[Press], model: TactileModel,
                 normals: list[Normals], current: Score, opts: TactileDiagnosisOptions,
                 say: Callable[[str], None]) -> None:
        self.data, self.presses, self.model, self.normals = data, presses, model, normals
        self.current, self.opts, self.say = current, opts, say
        self.findings: list[dict[str, Any]] = []
        self.rounds: list[dict[str, Any]] = []
        self.significant_before: set[str] = set()

    def has_candidates(self) -> bool:
        return True  # a round with nothing left to add clears nothing and ends the loop

    def propose(self) -> list[_Tried]:
        model, data, cur = self.model, self.data, self.current
        tried: list[_Tried] = []
        for name in self.opts.effects:
            if name in model.effects:
                continue
            self.say(f"trying {name}")
            cand = PROPOSERS[name](model, data, self.presses, self.normals)
            if cand is None:
                continue
            same = (cand.sigma_mm, cand.skirt_mm) == (model.sigma_mm, model.skirt_mm)
            nrm = self.normals if same else all_normals(data, self.presses, cand.sigma_mm,
                                                        cand.skirt_mm)
            sc = score(cand, data, nrm)[0]
            tried.append(_Tried(name, cur.neg2loglike - sc.neg2loglike, sc.n_params - cur.n_params,
                                sc, cand, nrm))
        self.rounds.append({t.name: {"delta_bic": round(t.score.bic - cur.bic, 1),
                                     "chi2_per_dof": round(t.score.chi2_per_dof, 5)} for t in tried})
        return tried

    def reconsider(self, tried: list[_Tried]) -> list[_Tried]:
        return []  # the excess-share rule has no costlier second look

    def admits(self, t: _Tried) -> bool:
        cur = self.current
        return (cur.chi2_per_dof - t.score.chi2_per_dof
                > self.opts.min_excess_share * max(cur.chi2_per_dof - 1.0, 0.0))

    def review(self, tried: list[_Tried], cleared: list[_Tried]) -> None:
        good = {t.name for t in cleared}
        if self.findings:  # significant last round, no longer once the finding is in
            last = self.findings[-1]["effect"]
            self.findings[-1]["alternatives"] = sorted(self.significant_before - good - {last})
        self.significant_before = good

    def alternatives(self, best: _Tried, cleared: list[_Tried], tried: list[_Tried]) -> list[_Tried]:
        return []  # named by :meth:`review` in the next round

    def accept(self, best: _Tried, alternatives: list[_Tried], threshold: float) -> None:
        data, current = self.data, self.current
        sc, model, normals, presses = best.score, best.model, best.normals, self.presses
        if "led_directions" in model.effects:
            model, presses, normals = _fit_with_presses(
                model, data, presses, passes=2 if best.name == "led_directions" else 1)
            sc = score(model, data, normals)[0]
        delta = sc.bic - current.bic
        self.findings.append(finding_entry(
            best.name, effect_params(best.name, model, data.mm_per_px),
            round(sc.stats.rms_dn * 255, 4), round(sc.chi2_per_dof, 5),
            f"χ²/dof {current.chi2_per_dof:.3f} → {sc.chi2_per_dof:.3f}, "
            f"ΔBIC {delta:.0f} over {sc.stats.n_pixels} values", [], delta_bic=round(delta, 1)))
        self.say(f"accepted {best.name}: χ²/dof {sc.chi2_per_dof:.3f}")
        self.model, self.presses, self.normals, self.current = model, presses, normals, sc

    def settle(self, tried: list[_Tried]) -> None:
        return None


# scalar effects that can be taken out again: the attribute and its baseline value
REMOVABLE = {"elastomer_blur": ("sigma_mm", TactileModel().sigma_mm),
             "optical_spread": ("spread_mm", 0.0), "gel_sink_in": ("skirt_mm", 0.0),
             "camera_gamma": ("gamma", 1.0)}


def swap_alternatives(search: _TactileSearch) -> None:
    """Undo a greedy choice the data disown: for every finding of a scalar effect
    (:data:`REMOVABLE`), take it out and put in its place, in turn, each such effect its round
    named as explaining the data about as well, or refit each such effect accepted later
    without it (fitted, the presses refitted under fitted lights); keep the best when the
    final BIC is lower (a dropped finding leaves the findings; the one that replaces it says so
    in ``replaces`` and its evidence). Forward
    selection takes the best effect at the model of its round; two blurs that look alike
    before the lights are fitted (the surface's and the shading's) are told apart only
    afterwards."""
    data = search.data
    for f in list(search.findings):
        name = f["effect"]
        if name not in REMOVABLE or f not in search.findings:
            continue
        best: tuple[Score, str, TactileModel, list[Press], list[Normals]] | None = None
        rivals = [a for a in f["alternatives"] if a in REMOVABLE and a not in search.model.effects]
        # a scalar effect accepted later may be what this one stood in for: drop this one
        # and refit that one's scalar without it
        rivals += [e for e in search.model.effects if e in REMOVABLE and e != name]
        for alt in rivals:
            out = search.model.copy()
            for gone in {name, alt}:
                attr, base = REMOVABLE[gone]
                setattr(out, attr, base)
            out.effects = [e for e in out.effects if e not in {name, alt}]
            cand = PROPOSERS[alt](out, data, search.presses,
                                  all_normals(data, search.presses, out.sigma_mm, out.skirt_mm))
            if cand is None:
                continue
            presses = search.presses
            nrm = all_normals(data, presses, cand.sigma_mm, cand.skirt_mm)
            if "led_directions" in cand.effects:
                cand, presses, nrm = _fit_with_presses(cand, data, presses)
            sc = score(cand, data, nrm)[0]
            search.say(f"swapping {name} for {alt}: ΔBIC {sc.bic - search.current.bic:+.0f}")
            if sc.bic < search.current.bic and (best is None or sc.bic < best[0].bic):
                best = (sc, alt, cand, presses, nrm)
        if best is None:
            continue
        sc, alt, cand, presses, nrm = best
        if alt in search.model.effects:  # dropped: the later finding now carries it alone
            later = next(g for g in search.findings if g["effect"] == alt)
            later.update(params=effect_params(alt, cand, data.mm_per_px),
                         chi2_per_dof_after=round(sc.chi2_per_dof, 5), replaces=name,
                         evidence=f"{later['evidence']}; {name} (accepted before it, "
                         f"{f['params']}) dropped: {alt} refitted without it explains the "
                         f"data better (ΔBIC {sc.bic - search.current.bic:+.0f})")
            search.findings.remove(f)
            search.model, search.presses, search.normals, search.current = cand, presses, nrm, sc
            continue
        f.update(effect=alt, params=effect_params(alt, cand, data.mm_per_px),
                 alternatives=[name], swapped_from=name,
                 evidence=f"{f['evidence']}; then {name} swapped for {alt} once the other "
                 f"effects were in (ΔBIC {sc.bic - search.current.bic:+.0f}, χ²/dof "
                 f"{search.current.chi2_per_dof:.3f} → {sc.chi2_per_dof:.3f})")
        f["chi2_per_dof_after"] = round(sc.chi2_per_dof, 5)
        search.model, search.presses, search.normals, search.current = cand, presses, nrm, sc


def diagnose_tactile(
    real: RealPresses,
    ball_radius_mm: float,
    mm_per_px: float,
    indices: list[int] | None = None,
    options: TactileDiagnosisOptions | None = None,
    progress: Callable[[str], None] | None = None,
    exclude: np.ndarray | None = None,
) -> TactileDiagnosis:
    """Diagnose the tactile simulation against real ball presses.

    Parameters
    ----------
    real
        Press frames and the no-contact frame (display units).
    ball_radius_mm, mm_per_px
        The indenter (known) and the image pixel size.
    indices
        Presses to use (default all); the others are never looked at.
    exclude
        Optional ``P × H × W`` boolean pixels to leave out of every fit (e.g. markers), one
        frame per press used.
    """
    opts = options or TactileDiagnosisOptions()
    say = progress or (lambda _m: None)
    t0 = time.perf_counter()
    idx = list(range(len(real.images))) if indices is None else list(indices)
    images = real.images[idx].astype(np.float64)
    reference = real.reference.astype(np.float64)
    presses = initial_presses(images, reference, ball_radius_mm, mm_per_px)
    sigma = estimate_noise(images, presses, ball_radius_mm, mm_per_px)
    valid = clipped_mask(images)
    if exclude is not None:
        valid &= ~np.asarray(exclude, bool)[..., None]
    data = PressData(images, reference, valid, sigma, mm_per_px, ball_radius_mm)
    model = TactileModel()
    normals = all_normals(data, presses, model.sigma_mm, model.skirt_mm)
    model = fit_linear(model, data, normals)
    base_score, base_pred = score(model, data, normals)
    baseline = model.copy()
    base_loc = locate_residual(images, base_pred, variance(model, data, base_pred), data.valid,
                               normals)
    say(f"baseline χ²/dof {base_score.chi2_per_dof:.2f}")
    search = _TactileSearch(data, presses, model, normals, base_score, opts, say)
    forward_select(search, InformationCriterion.for_values(base_score.stats.n_pixels,
                                                           opts.min_delta_bic), opts.max_effects)
    swap_alternatives(search)
    findings, rounds = search.findings, search.rounds
    model, presses, normals = search.model, search.presses, search.normals
    accepted = {f["effect"] for f in findings}
    for f in findings:  # an effect accepted later is not an alternative
        f["alternatives"] = [a for a in f["alternatives"] if a not in accepted]
    final_score, final_pred = score(model, data, normals)
    final_loc = locate_residual(images, final_pred, variance(model, data, final_pred), data.valid,
                                normals)
    sig = final_score.chi2_per_dof > opts.unexplained_chi2
    fl = final_loc.report
    unexplained = unexplained_section(
        sig, ("structured residual left: " + fl["summary"]) if sig else
        f"residual within {opts.unexplained_chi2}× the noise (χ²/dof {final_score.chi2_per_dof:.2f})",
        fl["hotspots"] if sig else [])
    report = diagnosis_report(
        head={"format": "thintact-tactile-diagnosis/1", "source": real.source,
              "presses_used": idx, "ball_radius_mm": ball_radius_mm, "mm_per_px": mm_per_px},
        noise_rms_dn=[round(float(s) * 255, 4) for s in sigma],
        baseline=_stats_json(base_score), located=base_loc.report, findings=findings,
        final=_stats_json(final_score), unexplained=unexplained,
        after={"noise_rms_dn": {"noise_sigma": [float(s) for s in sigma]},
               "findings": {"rounds": rounds}, "final": {"final_located": final_loc.report}},
        tail={"presses": [{"index": i, "row_px": round(p.row, 3), "col_px": round(p.col, 3),
                           "x_mm": round((p.col - (data.shape[1] - 1) / 2) * mm_per_px, 4),
                           "y_mm": round((p.row - (data.shape[0] - 1) / 2) * mm_per_px, 4),
                           "depth_mm": round(p.depth_mm, 4)}
                          for i, p in zip(idx, presses, strict=True)],
              "seconds": round(time.perf_counter() - t0, 2),
              "units": "rms_dn in 8-bit DN (display units × 255); χ² per value with σ the "
                       "measured per-pixel noise"})
    return TactileDiagnosis(report, data, presses, baseline, model, base_pred, final_pred,
                            base_loc, final_loc, idx)
