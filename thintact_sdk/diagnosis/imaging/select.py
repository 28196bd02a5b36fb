"""Naming the missing physics: score every candidate effect, fit the best, accept effects
one at a time while the evidence clears the information criterion.

Round by round, at the current model (effects accepted so far, gains profiled):

1. *Score*: for each candidate, the first-order signature J (change of the prediction
   when each parameter moves by its typical step from the null value, nuisance directions
   projected out) gives the linearised improvement Δχ² = max_a (2aᵀJᵀWr − aᵀJᵀWJa),
   with one-sided parameters kept on their physical side.
2. *Fit*: a line search along each promising candidate's score direction ranks them (an
   optical candidate whose score could not reach the best few is not line-searched: each of
   its steps re-simulates); the best few are fitted in full (Levenberg-Marquardt on the
   profiled χ², finite-difference Jacobians, re-simulating).
3. *Accept* the best if Δχ² > k·ln(n) + margin (BIC with k parameters, n pixel values)
   and its effect on the prediction exceeds the systematic-error floor; candidates whose
   fit is as good within the BIC resolution are named as alternatives. The loop and the
   criterion are the ones tactile shares
   (:mod:`~thintact_sdk.diagnosis.core.forward_selection`); this module supplies the rounds.
4. *Under the floor*: when every candidate that clears Δχ² stays under the floor, the best
   is still accepted when it is decisive and stable under refit on each half of the frames
   (:func:`_stable_under_refit`): a floor must never hide a decisive effect.
5. *Revisit*: after each accepted effect, every earlier round's winner is left out or
   swapped for its round's fitted rivals, refitted jointly, and the lowest BIC kept
   (:func:`_revisit_rounds`).

W holds 1/(σ² + (sys_frac·signal)²): the systematic-error allowance.

This module is the *policy* (which effects to try, in which order, what to accept); the
numerical work is done by the generic optimisers of :mod:`~thintact_sdk.diagnosis.imaging.optimise`
on a :class:`Trial` (the model as a function of a flat parameter vector). What is special
about an effect (a start read off the data, a proxy, per-channel parameters, whether it may
move later) is declared with the effect (its :class:`~thintact_sdk.simulation.effects.FitSpec`),
never tested here by name. One :class:`~thintact_sdk.diagnosis.imaging.deadline.Deadline` bounds it all.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from thintact_sdk.diagnosis.core.forward_selection import InformationCriterion, forward_select
from thintact_sdk.diagnosis.imaging import optimise
from thintact_sdk.diagnosis.imaging.candidates import CANDIDATES, Candidate
from thintact_sdk.diagnosis.imaging.deadline import Deadline, DeadlineExpired
from thintact_sdk.diagnosis.imaging.forward_model import (
    DiagnosisModel,
    Evaluation,
    Values,
    evaluate_self_weighted,
)
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import Profile

#: ``(values before, values after) -> rms change of the prediction as a fraction of the rms
#: signal``, measured on data finer than the fit's (the unbinned recording of a binned fit)
FineAmplitude = Callable[[Values, Values], float]

#: failures of the simulator for one candidate (an effect combination it cannot model, a
#: missing optional path): the candidate is dropped and the log says why
SIMULATION_ERRORS = (ThinTactError, ImportError, NotImplementedError, ValueError)

#: an optical candidate (every line-search step re-simulates, seconds for a rotated or
#: refracted kernel) is line-searched only while its score times this could still reach the
#: ``n_fit``-th best line-search Δχ² of the round; measured line-search/score ratios on the
#: concealed set are 0.7-4.3 (geometry, a strongly nonlinear effect, 4.3)
LINE_SEARCH_REACH = 10.0

#: a candidate under the amplitude floor is still named when it is decisive and *stable under
#: refit*: refitted on each half of the fit frames (every other frame, the accepted effects
#: refitted with it), it clears the criterion on both halves and every fitted parameter of
#: each half lies within ``STABLE_REL`` of the whole fit's value plus ``STABLE_STEP`` of the
#: effect's typical step (so that a parameter near its null value has a scale). 25 % is the
#: parameter tolerance the diagnosis is held to (a 4 um blur within 1 um)
STABLE_REL = 0.25
STABLE_STEP = 0.05

#: the fitted rivals of an earlier round revisited after each accepted effect (best first)
REVISIT_RIVALS = 2

#: candidates under the floor checked for stability in a round that admitted none (best first)
STABLE_CHECKS = 2


@dataclass
class CandidateResult:
    """What one round learned about one candidate."""

    name: str
    k: int  # parameters fitted (held ones not counted): the BIC penalty's k
    score_dchi2: float
    vector: np.ndarray
    dchi2: float | None = None  # from the full fit
    fitted: np.ndarray | None = None
    evaluation: Evaluation | None = None
    amplitude_dn: float = 0.0  # rms change of the prediction caused by the fitted effect
    refined: bool = False  # Levenberg-Marquardt done (not only the line search)
    joint: Values = field(default_factory=dict)  # refitted values of earlier effects
    fine_amplitude: float | None = None  # relative change on the finer data (FineAmplitude)
    halves: list[np.ndarray] | None = None  # refitted on each half of the frames (stability)
    stable: bool | None = None  # decisive and stable under refit on the halves (None: not checked)


@dataclass
class Round:
    """One accepted effect with the evidence for it."""

    name: str
    vector: np.ndarray
    dchi2: float
    threshold: float
    k: int
    amplitude_dn: float
    alternatives: list[CandidateResult]
    ranking: list[CandidateResult]
    evaluation: Evaluation
    fine_amplitude: float | None = None
    #: named under the amplitude floor (a fraction of the rms signal) because its fit is
    #: decisive and stable under refit; the halves' parameter vectors
    below_floor: float | None = None
    halves: list[np.ndarray] | None = None
    #: the effect this round first accepted and a later round's revisit replaced, with the
    #: χ² the replacement saved (:func:`_revisit_rounds`)
    swapped_from: str | None = None
    swap_dchi2: float = 0.0
    #: effects accepted in earlier rounds that this one made unnecessary (dropped by the
    #: revisit, :func:`_revisit_rounds`): ``(name, parameters when dropped, BIC gain)``
    absorbed: list[tuple[str, np.ndarray, float]] = field(default_factory=list)


@dataclass
class BelowFloor:
    """A candidate whose fit cleared the Δχ² criterion but whose change of the prediction
    stayed under the amplitude floor: the data show it, but a change that small cannot be
    told from the simulator's own error, so it is reported, not named."""

    name: str
    dchi2: float
    threshold: float
    amplitude_fraction: float  # rms change of the prediction / rms signal
    fine_amplitude: float | None  # the same on the unbinned recording, when measured
    vector: np.ndarray
    halves: list[np.ndarray] | None = None  # refitted on each half of the frames (not stable)

    def to_json(self, profile: Profile) -> dict[str, object]:
        """``report.json`` ``below_floor`` entry (parameters in the contract's units)."""
        cand = CANDIDATES[self.name]
        out: dict[str, object] = {
            "effect": self.name, "params": cand.to_params(self.vector, profile),
            "dchi2": round(self.dchi2, 1), "threshold": round(self.threshold, 1),
            "amplitude_fraction": float(f"{self.amplitude_fraction:.3g}")}
        if self.fine_amplitude is not None:
            out["unbinned_amplitude_fraction"] = float(f"{self.fine_amplitude:.3g}")
        if self.halves is not None:
            out["refit_on_halves"] = [cand.to_params(h, profile) for h in self.halves]
        return out


@dataclass
class Selection:
    """Result of :func:`select_effects`."""

    values: Values
    rounds: list[Round]
    evaluation: Evaluation
    rejected: list[CandidateResult] = field(default_factory=list)
    log: list[str] = field(default_factory=list)
    below_floor: list[BelowFloor] = field(default_factory=list)


class Trial:
    """The model as a function of one flat vector: the effects ``names`` (their vectors
    concatenated in that order) set from it, every other effect at ``values``.

    This is the objective every optimiser of :mod:`~thintact_sdk.diagnosis.imaging.optimise` works
    on; with ``beta`` the gains (closed-form coefficients) are held fixed instead of solved.
    ``durations`` records the wall seconds of each evaluation.
    """

    def __init__(
        self, model: DiagnosisModel, values: Values, names: Iterable[str], beta: np.ndarray | None = None
    ) -> None:
        self.model = model
        self.values = dict(values)
        self.names = tuple(names)
        self.cands = [CANDIDATES[n] for n in self.names]
        self.offsets = np.cumsum([0, *(c.k for c in self.cands)])
        self.beta = beta
        self.durations: list[float] = []
        prof = model.profile
        self.box = optimise.Box(
            np.concatenate([c.lower(prof) for c in self.cands]),
            np.concatenate([c.upper(prof) for c in self.cands]),
        )
        self.step = np.concatenate([c.step(prof) for c in self.cands])
        self.data = optimise.WeightedData(model.data.measured_dn, model.weights)

    def pack(self, values: Values) -> np.ndarray:
        """The flat vector of ``values`` for :attr:`names`."""
        return np.concatenate([np.asarray(values[n], np.float64) for n in self.names])

    def unpack(self, x: np.ndarray) -> Values:
        """Every effect's values with :attr:`names` taken from ``x``."""
        out = dict(self.values)
        for n, a, b in zip(self.names, self.offsets[:-1], self.offsets[1:], strict=True):
            out[n] = np.array(x[a:b], np.float64)
        return out

    def active(self, include_slow: bool = False) -> list[int]:
        """Flat indices of the parameters to vary (the slow ones only with ``include_slow``;
        never those the model holds, :attr:`DiagnosisModel.held`)."""
        return [
            int(a) + i for c, a in zip(self.cands, self.offsets, strict=False)
            for i in self.model.free(c, include_slow)
        ]

    def channel_blocks(self) -> list[list[int]]:
        """Flat indices of each channelwise effect (parameter j acts on channel j)."""
        return [list(range(int(a), int(a) + c.k))
                for c, a in zip(self.cands, self.offsets, strict=False) if c.channelwise]

    def __call__(self, x: np.ndarray) -> Evaluation:
        t0 = time.perf_counter()
        ev = self.model.evaluate(self.unpack(x), beta=self.beta)
        self.durations.append(time.perf_counter() - t0)
        return ev


def _parabola(trial: Trial, x: np.ndarray, ev: Evaluation, i: int, h: float) -> tuple[np.ndarray, Evaluation]:
    """:func:`optimise.parabola` on ``trial``; the first evaluation's time becomes the
    model's estimate of one slow simulation."""
    n0 = len(trial.durations)
    out = optimise.parabola(trial, x, ev, i, h, trial.box)
    trial.model.slow_sim_s = trial.durations[n0]
    return out


def score_candidate(
    model: DiagnosisModel, values: Values, ev0: Evaluation, cand: Candidate
) -> CandidateResult:
    """Linearised (score-test) improvement of adding ``cand`` to ``values``."""
    prof = model.profile
    null, step = cand.null(prof), cand.score_step(prof)
    signed = cand.signed or (True,) * cand.k
    if cand.domain == "linear":
        trial = dict(values)
        trial[cand.name] = null.copy()
        ev = model.evaluate(trial)
        vec = ev.beta[:, 1:].ravel() if ev.beta.shape[1] > 1 else null
        d = ev0.chi2 - ev.chi2
        return CandidateResult(cand.name, cand.k, d, vec, d, vec, ev, refined=True)
    if cand.search is not None:
        return _score_by_search(model, values, ev0, cand)
    at_gains = Trial(model, values, (cand.name,), beta=ev0.beta)
    cols: list[np.ndarray] = []
    fast = model.free(cand, include_slow=False)
    if cand.channelwise:
        diff = at_gains(null + step * np.isin(np.arange(cand.k), fast)).pred_dn - ev0.pred_dn
        for i in fast:
            ci = np.zeros_like(diff)
            ci[..., i] = diff[..., i] / step[i]
            cols.append(ci)
    else:
        for i in fast:
            v = null.copy()
            v[i] += step[i]
            v = at_gains.box.clip(v)
            d_i = float(v[i] - null[i]) or step[i]
            cols.append((at_gains(v).pred_dn - ev0.pred_dn) / d_i)
    a, gain = optimise.score_test(
        cols, model.data.measured_dn - ev0.pred_dn, model.weights,
        model.nuisance_directions(values, ev0), [signed[i] for i in fast],
    )
    full = np.zeros(cand.k)
    full[fast] = a
    vec = at_gains.box.clip(null + full)
    return CandidateResult(cand.name, len(model.free(cand)), gain, vec)


def _score_by_search(
    model: DiagnosisModel, values: Values, ev0: Evaluation, cand: Candidate
) -> CandidateResult:
    """Try the values the effect's :class:`~thintact_sdk.diagnosis.imaging.candidates.DataSearch`
    reads off the data, keep the best, and refine it by a parabola unless the data give it
    exactly. No new simulation is needed for effects after the gain."""
    assert cand.search is not None
    m = model.data.measured_dn[model.fit_mask]
    null = cand.null(model.profile)
    trial = Trial(model, values, (cand.name,))
    best_d, best_v, best_ev = 0.0, null, None
    for v in cand.search.starts(m, model.profile):
        e = trial(v)
        if ev0.chi2 - e.chi2 > best_d:
            best_d, best_v, best_ev = ev0.chi2 - e.chi2, v, e
    if best_ev is None:
        return CandidateResult(cand.name, len(model.free(cand)), 0.0, null)
    if cand.search.exact(best_v, m):
        return CandidateResult(cand.name, len(model.free(cand)), best_d, best_v, best_d, best_v,
                               best_ev, refined=True)
    v, e = _parabola(trial, best_v, best_ev, 0, cand.search.refine_width(best_v))
    d = ev0.chi2 - e.chi2
    return CandidateResult(cand.name, len(model.free(cand)), d, v, d, v, e, refined=True)


def fit_candidate(
    model: DiagnosisModel,
    values: Values,
    ev0: Evaluation,
    res: CandidateResult,
    deadline: Deadline,
    n_iter: int = 6,
    refine: bool = True,
    jointly: tuple[str, ...] = (),
) -> CandidateResult:
    """Fit ``res.name`` with the gains profiled; fills ``dchi2``, ``fitted``,
    ``evaluation`` and ``amplitude_dn``.

    A line search along the score direction (0.5 to 8 times the linear estimate, which
    a large effect overshoots or undershoots) gives the start; Levenberg-Marquardt with
    finite-difference Jacobians refines the cheap parameters together with those of the
    effects in ``jointly`` that may move; parameters that need the simulator's slow path
    are refined last by a parabola through three values, when the time budget allows.
    """
    cand = CANDIDATES[res.name]
    if res.evaluation is not None and res.fitted is not None and (res.refined or not refine):
        res.dchi2 = ev0.chi2 - res.evaluation.chi2
        res.amplitude_dn = _amplitude(model, ev0, res.evaluation)
        return res
    if res.evaluation is not None and res.fitted is not None:
        cur, ev = res.fitted, res.evaluation
    else:
        trial = Trial(model, values, (cand.name,))
        null = cand.null(model.profile)
        direction = res.vector - null
        if not np.any(direction):
            direction = 0.3 * trial.step * np.isin(np.arange(cand.k), trial.active())
        cur, ev = optimise.line_search(trial, null, ev0, direction, trial.box, deadline)
    if refine:
        joint = tuple(
            n for n in jointly if n in values and CANDIDATES[n].joint_refit and n != cand.name
        )
        new_vals, ev = _refine(model, cand, values, cur, ev, n_iter, deadline, joint)
        cur = new_vals.pop(cand.name)
        res.joint = new_vals
        res.refined = True
    res.fitted = cur
    res.evaluation = ev
    res.dchi2 = ev0.chi2 - ev.chi2
    res.amplitude_dn = _amplitude(model, ev0, ev)
    return res


def _refine(
    model: DiagnosisModel,
    cand: Candidate,
    values: Values,
    cur: np.ndarray,
    ev: Evaluation,
    n_iter: int,
    deadline: Deadline,
    jointly: tuple[str, ...] = (),
) -> tuple[Values, Evaluation]:
    """Levenberg-Marquardt on the candidate's cheap parameters together with those of the
    effects named in ``jointly`` (accepted earlier: their values may move too), then the
    channel polish and the slow parameters; returns the new values of all of them."""
    vals = dict(values)
    vals[cand.name] = cur
    iters = n_iter + 2 if cand.channelwise and not jointly else n_iter
    names = (cand.name, *jointly)
    joint = Trial(model, vals, names)
    x, ev = optimise.levenberg_marquardt(
        joint, joint.pack(vals), ev, joint.data, joint.box, 0.01 * joint.step, joint.active(),
        deadline, iters, joint.channel_blocks(),
    )
    vals = joint.unpack(x)
    own = Trial(model, vals, (cand.name,))
    cur = vals[cand.name]
    if cand.channelwise and not deadline.expired():
        cur, ev = optimise.channel_polish(own, cur, ev, own.data, own.box, own.step)
    slow = [i for i in cand.slow_params if i in model.free(cand)]
    for i in slow:
        if not deadline.allows(3.5 * model.slow_sim_s):
            break
        cur, ev = _parabola(own, cur, ev, i, float(own.step[i]))
    vals[cand.name] = cur
    if slow and not np.allclose(cur[slow], 0.0) \
            and deadline.allows((cand.k + 2) * model.slow_sim_s):
        # one joint step over every parameter (each simulation on the slow path)
        cur, ev = optimise.levenberg_marquardt(
            own, cur, ev, own.data, own.box, 0.01 * own.step, own.active(include_slow=True),
            deadline, 1, own.channel_blocks(),
        )
        vals[cand.name] = cur
    return {n: vals[n] for n in names}, ev


def _amplitude(model: DiagnosisModel, ev0: Evaluation, ev: Evaluation) -> float:
    d = (ev.pred_dn - ev0.pred_dn)[model.fit_mask]
    return float(np.sqrt(np.mean(d * d))) if d.size else 0.0


def select_effects(
    model: DiagnosisModel,
    candidates: list[str],
    values: Values | None = None,
    max_effects: int = 4,
    n_fit: int = 2,
    margin: float = 25.0,
    amp_floor: float = 6e-4,
    alt_tol: float | None = None,
    deadline: Deadline | None = None,
    progress: Callable[[str], None] | None = None,
    fine_amplitude: FineAmplitude | None = None,
) -> Selection:
    """Greedy forward selection of effects (module docstring).

    Parameters
    ----------
    candidates
        Effect names to consider.
    values
        Effects already in the model (fixed at these values; refitted with each round's
        winner only through the gains).
    n_fit
        How many of the best candidates after the line search get a full fit each round.
    margin
        Added to the BIC penalty k·ln(n) (Δχ² units).
    amp_floor
        The accepted effect must change the prediction by at least this fraction of the
        rms signal (below it, honest discretisation differences could be the cause).
    alt_tol
        Δχ² within which another candidate counts as an equally good explanation
        (default 2·ln(n) + 0.2 % of the winner's Δχ²).
    deadline
        The run's time budget (default: none). When it expires the selection stops at the
        next round and keeps the effects accepted so far.
    fine_amplitude
        For a fit on binned data: a candidate that clears the Δχ² criterion but changes the
        binned prediction by less than ``amp_floor`` is accepted when its change on the
        finer (unbinned) data reaches ``amp_floor`` there. Binning averages away the fine
        structure of e.g. a mask shift (a 7 um shift of the paper's device changes its
        8×8-binned prediction by 4e-4 of the signal), while the floor is about the
        simulator's own accuracy, a property of the unbinned model.
    """
    deadline = deadline or Deadline.never()
    say = progress or (lambda _m: None)
    state = _SelectionState(model, dict(values or {}), [c for c in candidates if c not in (values or {})])
    criterion = InformationCriterion.for_values(model.n_fit, margin)
    sig = (state.ev.pred_dn - model.black)[model.fit_mask]
    signal_rms = float(np.sqrt(np.mean(sig * sig))) if sig.size else 1.0
    search = _ImagingSearch(state, criterion, n_fit, signal_rms, amp_floor, alt_tol, deadline, say,
                            fine_amplitude)
    forward_select(search, criterion, max_effects)
    return Selection(state.values, state.rounds, state.ev, state.rejected, state.log, state.below_floor)


class _ImagingSearch:
    """The imaging side of :func:`~thintact_sdk.diagnosis.core.forward_selection.forward_select`:
    rounds of score, line search and fit (:func:`_round_candidates`); the amplitude floor
    (binned, or on the finer data) as the admission rule; rivals within ``alt_tol`` as
    alternatives."""

    def __init__(self, state: _SelectionState, criterion: InformationCriterion, n_fit: int,
                 signal_rms: float, amp_floor: float, alt_tol: float | None, deadline: Deadline,
                 say: Callable[[str], None], fine_amplitude: FineAmplitude | None) -> None:
        self.state, self.criterion, self.n_fit = state, criterion, n_fit
        self.signal_rms, self.amp_floor, self.alt_tol = signal_rms, amp_floor, alt_tol
        self.deadline, self.say, self.fine_amplitude = deadline, say, fine_amplitude
        self.scores: list[CandidateResult] = []

    def has_candidates(self) -> bool:
        return bool(self.state.remaining)

    def propose(self) -> list[CandidateResult] | None:
        try:
            self.deadline.check("selection")
            fitted, self.scores = _round_candidates(
                self.state, self.n_fit, self.criterion.margin, self.criterion.ln_n, self.deadline,
                self.say)
        except DeadlineExpired as stop:
            self.state.log.append(str(stop))
            return None
        return fitted

    def admits(self, r: CandidateResult) -> bool:
        return r.amplitude_dn > self.amp_floor * self.signal_rms or _clears_fine_floor(
            self.state, r, self.amp_floor, self.fine_amplitude, self.say)

    def reconsider(self, tried: list[CandidateResult]) -> list[CandidateResult]:
        """Every candidate that cleared the criterion stayed under the amplitude floor: the
        best of them (by BIC gain) is named all the same when it is decisive and stable under
        refit (:func:`_stable_under_refit`); the next one is looked at only when it is not."""
        for r in sorted(tried, key=lambda t: -self.criterion.gain(t))[:STABLE_CHECKS]:
            if _stable_under_refit(self.state, r, self.criterion, self.deadline.share(0.5), self.say):
                return [r]
        return []

    def review(self, tried: list[CandidateResult], cleared: list[CandidateResult]) -> None:
        return None

    def alternatives(self, best: CandidateResult, cleared: list[CandidateResult],
                     tried: list[CandidateResult]) -> list[CandidateResult]:
        assert best.dchi2 is not None
        tol = self.alt_tol if self.alt_tol is not None else 2 * self.criterion.ln_n + 0.002 * best.dchi2
        return self.criterion.rivals(best, tried, tol)

    def accept(self, best: CandidateResult, alternatives: list[CandidateResult],
               threshold: float) -> None:
        self.state.accept(best, alternatives, self.scores, threshold)
        rnd = self.state.rounds[-1]
        if best.stable:  # only checked under the floor (reconsider)
            rnd.below_floor = best.amplitude_dn / max(self.signal_rms, 1e-12)
            rnd.halves = best.halves
        # at most 30 % of the time left, so that later rounds still happen
        _revisit_rounds(self.state, self.criterion, self.deadline.share(0.3), self.say)

    def settle(self, tried: list[CandidateResult]) -> None:
        state, crit = self.state, self.criterion
        state.rejected.extend(tried)
        state.below_floor = sorted(
            (BelowFloor(r.name, r.dchi2, crit.threshold(r.k), r.amplitude_dn / max(self.signal_rms, 1e-12),
                        r.fine_amplitude, np.asarray(r.fitted, float), r.halves)
             for r in tried if r.dchi2 is not None and r.fitted is not None and crit.clears(r)),
            key=lambda b: -b.dchi2)
        state.log.append("no remaining candidate clears the criterion: " + ", ".join(
            f"{r.name} Δχ²={r.dchi2:.1f} (needs {crit.threshold(r.k):.1f}), "
            f"amplitude {r.amplitude_dn:.2f} DN (floor {self.amp_floor * self.signal_rms:.2f})"
            + ("" if r.fine_amplitude is None
               else f", {r.fine_amplitude:.1e} of the signal unbinned (floor {self.amp_floor:.0e})")
            for r in tried
        ))


def _clears_fine_floor(
    state: _SelectionState, res: CandidateResult, amp_floor: float,
    fine_amplitude: FineAmplitude | None, say: Callable[[str], None],
) -> bool:
    """True when ``res``'s change of the prediction on the finer data reaches
    ``amp_floor`` of the signal there (``fine_amplitude``; False without one)."""
    if fine_amplitude is None or res.fitted is None:
        return False
    after = {**state.values, **res.joint, res.name: res.fitted}
    try:
        res.fine_amplitude = float(fine_amplitude(state.values, after))
    except SIMULATION_ERRORS as err:
        state.log.append(f"{res.name}: its amplitude on the unbinned data could not be "
                         f"simulated ({err})")
        return False
    say(f"{res.name}: changes the unbinned prediction by {res.fine_amplitude:.1e} of the signal")
    return res.fine_amplitude > amp_floor


def _half_model(model: DiagnosisModel, keep: np.ndarray) -> DiagnosisModel:
    """``model`` fitted on the frames ``keep`` (bool per frame) only: the same data, simulator
    cache and weights, the other frames weighted 0."""
    half = copy.copy(model)
    sel = np.asarray(keep, bool)[:, None, None, None]
    half.fit_mask = model.fit_mask & sel
    half.n_fit = int(half.fit_mask.sum())
    half.weights = np.where(sel, model.weights, 0.0)
    return half


def _stable_under_refit(state: _SelectionState, res: CandidateResult, criterion: InformationCriterion,
                        deadline: Deadline, say: Callable[[str], None]) -> bool:
    """True when ``res`` (a candidate whose fit cleared ``criterion`` on the fit frames) is
    decisive and stable under refit (:data:`STABLE_REL`): refitted from its whole fit on the
    even and on the odd frames, with the accepted effects refitted jointly, it clears the
    criterion on each half and its parameters agree. Fills ``res.halves`` and ``res.stable``."""
    model = state.model
    frames = model.data.measured_dn.shape[0]
    if res.fitted is None or frames < 2 or deadline.expired():
        return False
    cand = CANDIDATES[res.name]
    free = model.free(cand)
    tol = STABLE_REL * np.abs(res.fitted) + STABLE_STEP * np.abs(cand.step(model.profile))
    halves: list[np.ndarray] = []
    cleared = True
    for parity in (0, 1):
        half = _half_model(model, np.arange(frames) % 2 == parity)
        ev0 = half.evaluate(state.values)
        try:
            if cand.domain == "linear":  # closed-form terms: solved on the half
                part = score_candidate(half, state.values, ev0, cand)
            else:
                trial = Trial(half, state.values, (res.name,))
                part = CandidateResult(res.name, res.k, res.score_dchi2, res.vector,
                                       fitted=np.array(res.fitted, float), evaluation=trial(
                                           trial.pack({**state.values, res.name: res.fitted})))
                fit_candidate(half, state.values, ev0, part, deadline, jointly=state.accepted)
        except SIMULATION_ERRORS as err:
            state.log.append(f"{res.name}: its refit on half the frames failed in the simulator ({err})")
            return False
        assert part.fitted is not None
        halves.append(part.fitted)
        cleared &= InformationCriterion.for_values(half.n_fit, criterion.margin).clears(part)
    res.halves = halves
    agree = all(bool(np.all(np.abs(h[free] - res.fitted[free]) <= tol[free])) for h in halves)
    res.stable = cleared and agree
    say(f"{res.name}: under the amplitude floor; refitted on each half of the frames "
        + " / ".join(str(cand.to_params(h, model.profile)) for h in halves)
        + (": stable, named" if res.stable else ": not stable, not named"))
    return res.stable


def _drop_if_absorbed(state: _SelectionState, rnd: Round, criterion: InformationCriterion,
                      deadline: Deadline, say: Callable[[str], None]) -> bool:
    """Leave ``rnd``'s effect out, refit the newest other accepted one (with every other that
    may move) and keep that model when its BIC is lower; True when it was dropped."""
    model = state.model
    last = next(r for r in reversed(state.rounds) if r is not rnd)
    start = {n: v for n, v in state.values.items() if n != rnd.name}
    joint = tuple(r.name for r in state.rounds
                  if r is not rnd and r is not last and CANDIDATES[r.name].joint_refit)
    now = state.ev
    try:
        vals, ev = _refine(model, CANDIDATES[last.name], start, np.array(start[last.name], float),
                           model.evaluate(start), 6, deadline, joint)
    except SIMULATION_ERRORS as err:
        state.log.append(f"revisiting {rnd.name} (left out) failed in the simulator ({err})")
        return False
    gain = (now.chi2 - ev.chi2) + rnd.k * criterion.ln_n
    say(f"revisit {rnd.name} → left out: χ² {now.chi2:.1f} → {ev.chi2:.1f}")
    if gain <= 0:
        return False
    state.log.append(f"revisited {rnd.name}: no longer needed once {last.name} is in "
                     f"(BIC lower by {gain:.1f} without it); dropped")
    last.absorbed.append((rnd.name, np.asarray(rnd.vector, float), gain))
    state.rounds.remove(rnd)
    state.revised({**start, **vals}, ev.pred_dn)
    return True


def _revisit_rounds(state: _SelectionState, criterion: InformationCriterion, deadline: Deadline,
                    say: Callable[[str], None]) -> None:
    """Revisit each earlier round's choice now that a later effect is in the model: its
    winner is left out, or swapped, in turn, for the (at most :data:`REVISIT_RIVALS`, by BIC
    gain) rivals that round fitted (line search or full fit) and that cleared the criterion
    there; each variant is refitted
    jointly with the other accepted effects, and the best one whose BIC is lower than the
    current model's is kept (a swapped-out winner is named as its alternative; a left-out one
    is recorded by the newest round as absorbed). Greedy selection takes the best effect at
    the model of its round: a uniform veil can fit a recording better than mask leakage only
    until a pixel blur is in the model, and leakage can stand in for a blur on binned data
    until the blur itself is in (its joint refit then goes to 0)."""
    if len(state.rounds) < 2:
        return
    changed = False
    for rnd in list(state.rounds[:-1]):
        if deadline.expired():
            return
        changed |= _revisit_round(state, rnd, criterion, deadline, say)
    if changed and len(state.rounds) > 1:
        # the model changed under the later rounds' choices too: one more pass, every round
        for rnd in list(state.rounds):
            if deadline.expired() or rnd not in state.rounds:
                return
            _revisit_round(state, rnd, criterion, deadline, say)


def _revisit_round(state: _SelectionState, rnd: Round, criterion: InformationCriterion,
                   deadline: Deadline, say: Callable[[str], None]) -> bool:
    """One round of :func:`_revisit_rounds`; True when its effect was dropped or swapped."""
    model = state.model
    if _drop_if_absorbed(state, rnd, criterion, deadline, say):
        return True
    rivals = sorted((r for r in rnd.ranking
                     if r.fitted is not None and r.name != rnd.name
                     and r.name not in state.values and r.dchi2 is not None and criterion.clears(r)),
                    key=lambda r: -criterion.gain(r))[:REVISIT_RIVALS]
    now = state.ev
    best: tuple[float, CandidateResult, Values, Evaluation] | None = None
    for riv in rivals:
        assert riv.fitted is not None
        start = {n: v for n, v in state.values.items() if n != rnd.name}
        cand = CANDIDATES[riv.name]
        joint = tuple(n for n in state.accepted
                      if n != rnd.name and n in start and CANDIDATES[n].joint_refit)
        start[riv.name] = riv.fitted
        try:
            ev_start = model.evaluate(start)
            vals, ev = _refine(model, cand, start, np.array(riv.fitted, float), ev_start, 6,
                               deadline, joint)
        except SIMULATION_ERRORS as err:
            state.log.append(f"revisiting {rnd.name} with {riv.name} failed in the simulator ({err})")
            continue
        gain = (now.chi2 - ev.chi2) - (riv.k - rnd.k) * criterion.ln_n
        say(f"revisit {rnd.name} → {riv.name}: χ² {now.chi2:.1f} → {ev.chi2:.1f}")
        if gain > 0 and (best is None or gain > best[0]):
            best = (gain, riv, {**start, **vals}, ev)
    if best is None:
        return False
    gain, riv, vals, ev = best
    old = rnd.name
    others = [r.name for r in state.rounds if r is not rnd]
    state.log.append(f"revisited {old}: {riv.name} explains the data better once "
                     f"{', '.join(others)} {'is' if len(others) == 1 else 'are'} in "
                     f"(BIC lower by {gain:.1f}); swapped")
    assert riv.fitted is not None and riv.dchi2 is not None
    displaced = CandidateResult(old, rnd.k, 0.0, rnd.vector, dchi2=rnd.dchi2, fitted=rnd.vector,
                                evaluation=rnd.evaluation, refined=True)
    rnd.name, rnd.vector, rnd.k, rnd.dchi2 = riv.name, vals[riv.name], riv.k, riv.dchi2
    rnd.threshold = criterion.threshold(riv.k)
    rnd.amplitude_dn, rnd.fine_amplitude = riv.amplitude_dn, riv.fine_amplitude
    rnd.alternatives = [displaced]
    rnd.evaluation = riv.evaluation if riv.evaluation is not None else rnd.evaluation
    rnd.swapped_from, rnd.swap_dchi2 = old, gain
    rnd.below_floor, rnd.halves = None, None
    state.remaining = [c for c in state.remaining if c != riv.name]
    state.revised({n: v for n, v in vals.items() if n != old}, ev.pred_dn)
    return True


class _SelectionState:
    """What the greedy selection carries from round to round."""

    def __init__(self, model: DiagnosisModel, values: Values, remaining: list[str]) -> None:
        self.model = model
        self.values = values
        self.remaining = remaining
        self.rounds: list[Round] = []
        self.rejected: list[CandidateResult] = []
        self.log: list[str] = []
        self.accepted: tuple[str, ...] = ()
        self.below_floor: list[BelowFloor] = []
        #: each candidate's score Δχ² in the latest round that scored it
        self.last_score: dict[str, float] = {}
        self.ev = evaluate_self_weighted(model, values)

    def revised(self, values: Values, pred_dn: np.ndarray) -> None:
        """A revisit changed the accepted effects (:attr:`rounds` already says which):
        ``values`` are the refitted ones, ``pred_dn`` their prediction (the new reference of
        the fit weights)."""
        self.values = values
        for r in self.rounds:
            r.vector = np.asarray(values[r.name], float)
        self.accepted = tuple(r.name for r in self.rounds)
        self.model.set_reference(pred_dn)
        self.ev = self.model.evaluate(values)

    def drop(self, name: str, why: str) -> None:
        """Leave ``name`` out of the selection (the simulator failed on it)."""
        self.log.append(f"{name} left out: {why}")
        if name in self.remaining:
            self.remaining.remove(name)

    def accept(
        self, best: CandidateResult, alts: list[CandidateResult], scores: list[CandidateResult],
        threshold: float,
    ) -> None:
        """Add ``best`` to the model (with the refitted values of earlier effects)."""
        assert best.fitted is not None and best.evaluation is not None and best.dchi2 is not None
        self.values.update(best.joint)
        for rnd in self.rounds:
            if rnd.name in best.joint:
                rnd.vector = best.joint[rnd.name]
        self.values[best.name] = best.fitted
        self.accepted = (*self.accepted, best.name)
        self.rounds.append(Round(best.name, best.fitted, best.dchi2, threshold, best.k,
                                 best.amplitude_dn, alts, scores, best.evaluation,
                                 best.fine_amplitude))
        self.log.append(f"accepted {best.name}: Δχ² {best.dchi2:.1f} > {threshold:.1f}")
        alt_names = {a.name for a in alts}
        self.remaining = [c for c in self.remaining if c != best.name and c not in alt_names]
        self.model.set_reference(best.evaluation.pred_dn)
        self.ev = self.model.evaluate(self.values)


def _round_candidates(
    state: _SelectionState,
    n_fit: int,
    margin: float,
    ln_n: float,
    deadline: Deadline,
    say: Callable[[str], None],
) -> tuple[list[CandidateResult], list[CandidateResult]]:
    """One round: score every remaining candidate, line-search the promising ones, fit the
    best ``n_fit`` in full, start the proxied ones from their sources' fits.

    Returns the fitted candidates and the score ranking."""
    model, vals, ev = state.model, state.values, state.ev
    scores = []
    # candidates that need no new simulation first: when the budget runs out while the
    # optical ones are re-simulated (seconds each with a refracted or rotated kernel), the
    # cheap ones have still been scored; within each group the strongest evidence of the
    # previous round first (registration order in the first round)
    order = sorted(state.remaining, key=lambda n: (CANDIDATES[n].domain == "optical",
                                                   -state.last_score.get(n, 0.0)))
    for name in order:
        if CANDIDATES[name].proxy is not None:
            continue
        if deadline.expired():
            break
        try:
            res = score_candidate(model, vals, ev, CANDIDATES[name])
        except SIMULATION_ERRORS as err:
            state.drop(name, f"the simulator cannot model it here ({err})")
            continue
        scores.append(res)
        state.last_score[name] = res.score_dchi2
        say(f"score {name}: Δχ² ≈ {res.score_dchi2:.1f}")
    scores.sort(key=lambda r: -(r.score_dchi2 - r.k * ln_n))
    fitted: list[CandidateResult] = []
    for res in scores:
        if res.score_dchi2 - res.k * ln_n < 0.5 * margin and fitted:
            continue
        if fitted and deadline.expired():
            break
        if _out_of_reach(res, fitted, n_fit):
            state.log.append(f"{res.name} not line-searched: score Δχ² {res.score_dchi2:.0f} "
                             f"cannot reach the {n_fit} best of the round")
            continue
        try:
            fit_candidate(model, vals, ev, res, deadline, refine=False)
        except SIMULATION_ERRORS as err:
            state.drop(res.name, f"fitting it failed in the simulator ({err})")
            continue
        fitted.append(res)
        say(f"line search {res.name}: Δχ² = {res.dchi2:.1f}")
    fitted.sort(key=lambda r: -((r.dchi2 or 0.0) - r.k * ln_n))
    for res in fitted[:n_fit]:
        if (res.dchi2 or 0.0) - res.k * ln_n < 0.5 * margin:
            continue
        # one fit may use at most 40 % of the time left, so later rounds still happen
        # (a fit on the simulator's slow path needs every second it can get)
        cand = CANDIDATES[res.name]
        fit_deadline = deadline if (cand.slow_params or cand.costly) else deadline.share(0.4)
        try:
            fit_candidate(model, vals, ev, res, fit_deadline, jointly=state.accepted)
        except SIMULATION_ERRORS as err:
            state.drop(res.name, f"fitting it failed in the simulator ({err})")
            fitted.remove(res)
            continue
        say(f"fit {res.name}: Δχ² = {res.dchi2:.1f}, amplitude {res.amplitude_dn:.2f} DN")
    _fit_proxied(state, fitted, deadline, say)
    return fitted, scores


def _out_of_reach(res: CandidateResult, fitted: list[CandidateResult], n_fit: int) -> bool:
    """True when ``res`` re-simulates (optical) and even :data:`LINE_SEARCH_REACH` times its
    score stays below the ``n_fit``-th best line-search Δχ² so far: it could not be among
    the candidates fitted in full, so its line search would only spend simulations."""
    if CANDIDATES[res.name].domain != "optical" or len(fitted) < n_fit:
        return False
    best = sorted((r.dchi2 or 0.0 for r in fitted), reverse=True)
    return LINE_SEARCH_REACH * res.score_dchi2 < best[n_fit - 1]


def _fit_proxied(
    state: _SelectionState,
    fitted: list[CandidateResult],
    deadline: Deadline,
    say: Callable[[str], None],
) -> None:
    """Effects too expensive to score (their :class:`~thintact_sdk.diagnosis.imaging.candidates.Proxy`)
    start where their source effect's fit points and are refined by parabolas; each adds a
    fitted result to ``fitted``."""
    model, ev0 = state.model, state.ev
    for name in list(state.remaining):
        cand = CANDIDATES[name]
        px = cand.proxy
        if px is None:
            continue
        src = next((r for r in fitted if r.name == px.source and r.fitted is not None), None)
        if src is None or src.fitted is None:
            continue
        start = px.start(src.fitted, model.profile)
        if start is None or not deadline.allows(4.5 * model.slow_sim_s):
            continue
        trial = Trial(model, state.values, (name,))
        cur = trial.box.clip(start)
        try:
            ev = trial(cur)
            model.slow_sim_s = trial.durations[-1]
            for j, width in enumerate(px.widths):
                if j > 0 and not deadline.allows(3.5 * model.slow_sim_s):
                    break
                for i in model.free(cand):
                    cur, ev = _parabola(trial, cur, ev, i, width * abs(float(cur[i])))
        except SIMULATION_ERRORS as err:
            state.drop(name, f"fitting it from {px.source} failed in the simulator ({err})")
            continue
        res = CandidateResult(name, len(model.free(cand)), 0.0, cur, ev0.chi2 - ev.chi2, cur, ev,
                              refined=True)
        res.amplitude_dn = _amplitude(model, ev0, ev)
        fitted.append(res)
        say(f"{name} (from the {px.source} fit): {cand.to_params(cur, model.profile)}, "
            f"Δχ² = {res.dchi2:.1f}")
