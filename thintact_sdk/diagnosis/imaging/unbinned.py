"""The unbinned stage of a binned diagnosis: effects finer than a block, named at full size.

A large recording is diagnosed on its sensor binned ``b × b``
(:mod:`~thintact_sdk.diagnosis.imaging.binning`): exact for every effect acting on scales of a block
or more, but an effect whose whole signature lies inside a block is averaged away. A
Gaussian sensor blur of σ = 6 um on the paper's 10 um pixels changes the 8×8-binned
prediction by far less than the noise, so the binned stage names nothing; on the unbinned
frames it raises χ²/dof to 1.0018 over 47 million pixel values, 8.7 standard deviations
above the noise (``tools/diagnose_paper_size.py --case sensor_blur``).

So after the binned selection, the model it accepted is evaluated on the unbinned frames.
When their χ² lies more than :data:`EXCESS_Z` standard deviations above its noise-only
expectation, the same greedy selection (:func:`~thintact_sdk.diagnosis.imaging.select.select_effects`,
same BIC rule, margin and amplitude floor) runs on a few of them over the candidates that
can act below a block and that re-simulate cheaply at full size: every effect after the
imaging kernel (the full-size kernel is built once and reused), except the closed-form
linear ones (smooth by construction, so the binned stage saw them whole). Kernel-stage
effects were screened on the binned data, where their structure (mask cells of several
sensor pixels) survives; each of their steps here would rebuild a full-size kernel.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from thintact_sdk.diagnosis.imaging.candidates import CANDIDATES
from thintact_sdk.diagnosis.imaging.deadline import Deadline
from thintact_sdk.diagnosis.imaging.forward_model import (
    DiagnosisModel,
    SimulateFn,
    Values,
    default_simulate,
    evaluate_self_weighted,
    full_size_stats,
)
from thintact_sdk.diagnosis.imaging.recording_data import DiagnosisData, subset_frames
from thintact_sdk.diagnosis.imaging.select import BelowFloor, Selection, select_effects
from thintact_sdk.diagnosis.imaging.stats import default_variance_fn
from thintact_sdk.simulation.effects import EFFECTS

UNBINNED_FRAMES = 4
"""Unbinned frames the stage evaluates and fits on (spread over the recording)."""

EXCESS_Z = 3.0
"""The stage runs when the unbinned χ² exceeds its noise-only expectation ``n`` by more than
this many standard deviations ``√(2n)`` (one-sided p ≈ 1e-3; a 25 um scene blur on the
paper's device: 4.5). It only decides whether to look: what is named there must still clear
the BIC rule and the amplitude floor."""

UNBINNED_BUDGET_S = 120.0
"""Default wall-clock budget of the stage (s)."""


@dataclass
class UnbinnedInput:
    """What :func:`~thintact_sdk.diagnosis.imaging.engine.diagnose` needs for the unbinned stage.

    Attributes
    ----------
    data
        The unbinned recording (the diagnosis itself runs on its binned copy).
    bin_factor
        The block side ``b`` of the binned copy.
    frames
        Unbinned frames to evaluate and fit on.
    budget_s
        Wall-clock budget of the stage.
    simulate
        The simulator function for the unbinned frames (``None``: the model's default;
        :func:`~thintact_sdk.diagnosis.imaging.binning.simulate_float32` at full size).
    """

    data: DiagnosisData
    bin_factor: int
    simulate: SimulateFn | None = None
    frames: int = UNBINNED_FRAMES
    budget_s: float = UNBINNED_BUDGET_S


@dataclass(frozen=True)
class FullSizeAlternative:
    """An effect that explains the unbinned frames about as well as an accepted one."""

    name: str
    dchi2: float  # its improvement in place of the accepted effect
    own_dchi2: float  # the accepted effect's
    vector: np.ndarray
    tol: float = 0.0  # the alternative tolerance (Δχ²)
    amplitude_dn: float = 0.0  # its rms change of the prediction there

    @property
    def better(self) -> bool:
        """True when it beats the accepted effect by more than the tolerance (it replaces it)."""
        return self.dchi2 > self.own_dchi2 + self.tol


@dataclass
class UnbinnedStage:
    """What the unbinned stage did (``report.json`` ``binned.unbinned_stage``).

    Attributes
    ----------
    excess_z
        Standard deviations by which the unbinned χ² of the binned stage's model lies above
        its noise-only expectation.
    ran
        Whether the excess started the selection.
    tried
        The candidates it considered.
    selection
        Its selection (None when it did not run).
    model, data
        The unbinned frames' model and data.
    refitted
        The binned stage's effects refitted on the unbinned frames (those binning only
        approximates: every one after the imaging kernel), their new values.
    alternatives
        Per accepted effect after the imaging kernel, the rivals that explain the unbinned
        frames about as well in its place (:func:`full_size_alternatives`).
    replaced
        Accepted effects a rival beat there by more than the tolerance: the rival takes its
        place (a sensor blur the binned data took for a scene blur).
    values
        Every effect's values after the stage (refits, new effects, replacements).
    check
        ``{"rms_dn", "chi2_per_dof"}`` of the binned stage's model on every unbinned frame
        (:func:`~thintact_sdk.diagnosis.imaging.binning.full_size_check`'s figures).
    """

    excess_z: float
    ran: bool = False
    tried: list[str] = field(default_factory=list)
    selection: Selection | None = None
    model: DiagnosisModel | None = None
    data: DiagnosisData | None = None
    check: dict[str, float] = field(default_factory=dict)
    refitted: Values = field(default_factory=dict)
    alternatives: dict[str, list[FullSizeAlternative]] = field(default_factory=dict)
    replaced: dict[str, FullSizeAlternative] = field(default_factory=dict)
    values: Values = field(default_factory=dict)
    amp_floor: float = 0.0

    def below_floor(self) -> list[BelowFloor]:
        """The stage's candidates that cleared the Δχ² criterion but not the amplitude floor
        (what would explain the excess, were the simulator exact)."""
        return [] if self.selection is None else list(self.selection.below_floor)

    def summary(self) -> str:
        """One sentence on what the stage found."""
        swaps = "".join(f" On them {a.name} explains the recording better than {old}, which the binned data "
                        f"preferred, and takes its place." for old, a in self.replaced.items())
        if not self.ran:
            return (f"The binned fit also fits the unbinned frames: their χ² lies {self.excess_z:.1f} standard "
                    f"deviations from the noise-only expectation (threshold {EXCESS_Z:g}).{swaps}")
        sel = self.selection
        text = f"The unbinned frames' χ² lay {self.excess_z:.1f} standard deviations above the noise."
        if self.refitted:
            text += (f" Refitted there: {', '.join(sorted(self.refitted))} (binning only approximates "
                     "effects after the imaging kernel).")
        text += swaps
        if sel is not None and sel.rounds:
            return text + f" Named there: {', '.join(r.name for r in sel.rounds)}."
        low = self.below_floor()
        if low:
            what = ", ".join(f"{b.name} (Δχ² {b.dchi2:.0f}, a change of {b.amplitude_fraction:.1e} of the signal)"
                             for b in low[:3])
            return (text + f" {what} would lower it further, but under the {self.amp_floor:.0e} amplitude "
                    "floor (the simulator's own accuracy): a change this small cannot be told from model "
                    "error, so nothing more is named.")
        return text + " No further effect that acts below a block clears the criterion there."

    def to_json(self) -> dict[str, object]:
        """The stage as ``report.json`` reports it."""
        sel = self.selection
        return {
            "summary": self.summary(),
            "below_floor": [b.to_json(self.model.profile) for b in self.below_floor()] if self.model else [],
            "excess_z": round(self.excess_z, 2), "threshold_z": EXCESS_Z, "ran": self.ran,
            "frames": 0 if self.data is None else self.data.n_frames,
            "before": dict(self.check),
            "refitted": sorted(self.refitted),
            "alternatives": {k: [a.name for a in v] for k, v in self.alternatives.items() if v},
            "replaced": {k: a.name for k, a in self.replaced.items()},
            "tried": list(self.tried),
            "accepted": [] if sel is None else [r.name for r in sel.rounds],
            "log": [] if sel is None else list(sel.log),
        }


def refit_effects(model: DiagnosisModel, values: Values, names: list[str], deadline: Deadline,
                  n_iter: int = 6) -> Values:
    """``values`` with the effects ``names`` refitted jointly on ``model``'s data
    (Levenberg-Marquardt from their current values, gains profiled, held and slow
    parameters fixed)."""
    from thintact_sdk.diagnosis.imaging import optimise
    from thintact_sdk.diagnosis.imaging.select import Trial

    ev = evaluate_self_weighted(model, values)
    trial = Trial(model, values, names)
    x, _ = optimise.levenberg_marquardt(trial, trial.pack(values), ev, trial.data, trial.box, 0.01 * trial.step,
                                        trial.active(), deadline, n_iter, trial.channel_blocks())
    return trial.unpack(x)


def excess_z(chi2_per_dof: float, n_values: int) -> float:
    """Standard deviations by which ``χ² = chi2_per_dof · n`` exceeds the mean ``n`` of a χ²
    with ``n`` degrees of freedom (standard deviation ``√(2n)``)."""
    return (chi2_per_dof - 1.0) * math.sqrt(max(n_values, 1) / 2.0)


def unbinned_candidates(candidates: list[str], accepted: Values) -> list[str]:
    """The candidates the unbinned stage tries: not accepted yet, acting after the imaging
    kernel (cheap to re-simulate at full size) and not closed-form linear."""
    return [c for c in candidates if c not in accepted and EFFECTS[c].stage != "kernel"
            and CANDIDATES[c].domain != "linear"]


def unbinned_stage(
    spec: UnbinnedInput,
    values: Values,
    candidates: list[str],
    *,
    sys_frac: float,
    max_effects: int,
    margin: float,
    amp_floor: float,
    held: dict[str, tuple[int, ...]] | None = None,
    progress: Callable[[str], None] | None = None,
) -> UnbinnedStage:
    """Evaluate ``values`` (the binned stage's model) on every unbinned frame and, when their
    χ² is in excess (:data:`EXCESS_Z`), select further effects on ``spec.frames`` of them.

    Parameters
    ----------
    spec
        The unbinned recording and the stage's frame count and budget.
    values
        The effects the binned stage accepted (fixed here except through joint refits).
    candidates
        The binned stage's candidates (filtered by :func:`unbinned_candidates`).
    sys_frac, max_effects, margin, amp_floor
        As for :func:`~thintact_sdk.diagnosis.imaging.select.select_effects`; ``max_effects`` is what
        the binned stage left.
    """
    say = progress or (lambda _m: None)
    simulate = spec.simulate or default_simulate
    # every frame for the decision (a 6 um sensor blur: 8.7 σ on 12 frames, 2.9 on 4), the
    # contract's χ² (noise model only: the fit's systematic allowance alone would pull a
    # right model's χ²/dof about 1 % under 1 at this signal)
    st = full_size_stats(spec.data, values, simulate, sys_frac)
    z = excess_z(st.chi2_per_dof, st.n_pixels)
    sub = subset_frames(spec.data, spec.frames)
    model = DiagnosisModel(sub, simulate, default_variance_fn(), sys_frac=sys_frac, cache_size=4, held=held)
    tried = unbinned_candidates(candidates, values)
    stage = UnbinnedStage(z, tried=tried, model=model, data=sub,
                          check={"rms_dn": round(st.rms_dn, 4), "chi2_per_dof": round(st.chi2_per_dof, 4)},
                          amp_floor=amp_floor)
    say(f"unbinned frames: χ² {z:+.1f} σ from the noise-only expectation")
    deadline = Deadline.after(spec.budget_s)
    if z > EXCESS_Z:
        stage.ran = True
        refit = unbinned_candidates(list(values), {})
        if refit:
            say(f"unbinned frames: χ² in excess ({z:.1f} σ): refitting {', '.join(refit)} at full size")
            values = refit_effects(model, values, refit, deadline)
            stage.refitted = {n: values[n] for n in refit}
        say(f"unbinned frames: trying {', '.join(tried)} at full size")
        stage.selection = select_effects(
            model, tried, values, max_effects=max_effects, margin=margin, amp_floor=amp_floor,
            deadline=deadline, progress=say)
        values = stage.selection.values
    after_kernel = unbinned_candidates(list(values), {})
    if after_kernel:
        rivals = unbinned_candidates(candidates, values)
        stage.alternatives = full_size_alternatives(model, values, after_kernel, rivals, deadline, say)
        for name, alts in list(stage.alternatives.items()):
            best = max(alts, key=lambda a: a.dchi2)
            if not best.better:
                continue
            # the unbinned frames prefer the rival beyond the tolerance: it takes the place
            say(f"unbinned frames: {best.name} explains them better than {name}: it replaces it")
            stage.replaced[name] = best
            values = {**{k: v for k, v in values.items() if k != name}, best.name: best.vector}
            stage.alternatives[name] = [a for a in alts if a is not best]
    stage.values = values
    return stage


def full_size_alternatives(model: DiagnosisModel, values: Values, names: list[str], rivals: list[str],
                           deadline: Deadline, progress: Callable[[str], None] | None = None,
                           ) -> dict[str, list[FullSizeAlternative]]:
    """For each accepted effect of ``names``, the ``rivals`` that explain ``model``'s frames
    about as well in its place (fitted without it; Δχ² within ``2·ln n + 0.2 %`` of its own,
    the selection's alternative rule).

    On binned data a rival that binning only approximates (a sensor blur) is judged on an
    approximate model: a 10 um sensor blur on the paper's device was named as a 50.6 um scene
    blur there (the scene blur commutes with binning and maps to the sensor by d/z ≈ 1/4.8)
    with no alternative, while on unbinned frames the two are the same within the noise. A
    rival is fitted only when its score test could reach the accepted effect's Δχ².
    """
    from thintact_sdk.diagnosis.imaging.select import fit_candidate, score_candidate

    say = progress or (lambda _m: None)
    ev_all = evaluate_self_weighted(model, values)
    ln_n = float(math.log(max(model.n_fit, 2)))
    out: dict[str, list[FullSizeAlternative]] = {}
    for name in names:
        without = {k: v for k, v in values.items() if k != name}
        ev0 = model.evaluate(without)
        own = ev0.chi2 - ev_all.chi2
        tol = 2 * ln_n + 0.002 * own
        for rival in rivals:
            if rival in values or deadline.expired():
                continue
            res = score_candidate(model, without, ev0, CANDIDATES[rival])
            if res.score_dchi2 < 0.5 * (own - tol):
                continue
            res = fit_candidate(model, without, ev0, res, deadline)
            say(f"unbinned frames: {rival} in place of {name}: Δχ² {res.dchi2 or 0:.0f} against {own:.0f}")
            if res.dchi2 is not None and res.fitted is not None and res.dchi2 > own - tol:
                out.setdefault(name, []).append(FullSizeAlternative(rival, float(res.dchi2), float(own),
                                                                     res.fitted, tol, res.amplitude_dn))
    return out
