"""Naming the missing physics: score every candidate effect, fit the best, accept effects
one at a time while the evidence clears the information criterion.

Round by round, at the current model (effects accepted so far, gains profiled):

1. *Score*: for each candidate, the first-order signature J (change of the prediction
   when each parameter moves by its typical step from the null value, nuisance directions
   projected out) gives the linearised improvement Δχ² = max_a (2aᵀJᵀWr − aᵀJᵀWJa),
   with one-sided parameters kept on their physical side.
2. *Fit*: the best few candidates are fitted in full (Levenberg-Marquardt on the profiled
   χ², finite-difference Jacobians, re-simulating).
3. *Accept* the best if Δχ² > k·ln(n) + margin (BIC with k parameters, n pixel values)
   and its effect on the prediction exceeds the systematic-error floor; candidates whose
   fit is as good within the BIC resolution are named as alternatives.

W holds 1/(σ² + (sys_frac·signal)²): the systematic-error allowance.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from thintact_sdk.diagnose.candidates import CANDIDATES, Candidate
from thintact_sdk.diagnose.model import DiagnosisModel, Evaluation, Values
from thintact_sdk.errors import ThinTactError

#: failures of the simulator for one candidate (an effect combination it cannot model, a
#: missing optional path): the candidate is dropped and the log says why
SIMULATION_ERRORS = (ThinTactError, ImportError, NotImplementedError, ValueError)


@dataclass
class CandidateResult:
    """What one round learned about one candidate."""

    name: str
    k: int
    score_dchi2: float
    vector: np.ndarray
    dchi2: float | None = None  # from the full fit
    fitted: np.ndarray | None = None
    evaluation: Evaluation | None = None
    amplitude_dn: float = 0.0  # rms change of the prediction caused by the fitted effect


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


@dataclass
class Selection:
    """Result of :func:`select_effects`."""

    values: Values
    rounds: list[Round]
    evaluation: Evaluation
    rejected: list[CandidateResult] = field(default_factory=list)
    log: list[str] = field(default_factory=list)


def _project(j: np.ndarray, d: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Remove from the columns ``j`` (K × P) their W-weighted projection on ``d`` (B × P)."""
    dw = d * w
    a = dw @ d.T
    coef = np.linalg.lstsq(a + 1e-12 * np.trace(a) * np.eye(len(a)) / max(len(a), 1), dw @ j.T, rcond=None)[0]
    return j - coef.T @ d


def _clip(c: Candidate, v: np.ndarray, model: DiagnosisModel) -> np.ndarray:
    return np.clip(v, c.lower(model.profile), c.upper(model.profile))


def _bounded_quadratic(u: np.ndarray, h: np.ndarray, signed: tuple[bool, ...]) -> tuple[np.ndarray, float]:
    """Maximise 2aᵀu − aᵀHa with a_i ≥ 0 for unsigned parameters (active-set, small K)."""
    k = len(u)
    free = np.ones(k, bool)
    a = np.zeros(k)
    for _ in range(k + 1):
        a = np.zeros(k)
        if free.any():
            hf = h[np.ix_(free, free)]
            a[free] = np.linalg.lstsq(hf + 1e-12 * np.trace(hf) * np.eye(int(free.sum())), u[free], rcond=None)[0]
        neg = [i for i in range(k) if free[i] and not signed[i] and a[i] < 0]
        if not neg:
            break
        free[neg] = False
    return a, float(2 * a @ u - a @ h @ a)


def score_candidate(
    model: DiagnosisModel, values: Values, ev0: Evaluation, cand: Candidate
) -> CandidateResult:
    """Linearised (score-test) improvement of adding ``cand`` to ``values``."""
    prof = model.profile
    null, step = cand.null(prof), cand.step(prof)
    signed = cand.signed or (True,) * cand.k
    resid = model.data.measured_dn - ev0.pred_dn
    w = model.weights
    if cand.domain == "linear":
        trial = dict(values)
        trial[cand.name] = null.copy()
        ev = model.evaluate(trial)
        vec = ev.beta[:, 1:].ravel() if ev.beta.shape[1] > 1 else null
        return CandidateResult(cand.name, cand.k, ev0.chi2 - ev.chi2, vec, ev0.chi2 - ev.chi2, vec, ev)
    if cand.name == "saturation":
        return _score_saturation(model, values, ev0, cand)
    cols: list[np.ndarray] = []
    if cand.channelwise:
        trial = dict(values)
        trial[cand.name] = null + step
        diff = model.evaluate(trial, beta=ev0.beta).pred_dn - ev0.pred_dn
        for i in range(cand.k):
            ci = np.zeros_like(diff)
            ci[..., i] = diff[..., i] / step[i]
            cols.append(ci)
    else:
        for i in range(cand.k):
            trial = dict(values)
            v = null.copy()
            v[i] += step[i]
            trial[cand.name] = _clip(cand, v, model)
            d_i = float(trial[cand.name][i] - null[i]) or step[i]
            cols.append((model.evaluate(trial, beta=ev0.beta).pred_dn - ev0.pred_dn) / d_i)
    nuis = model.nuisance_directions(values, ev0)
    u = np.zeros(cand.k)
    h = np.zeros((cand.k, cand.k))
    for c in range(resid.shape[3]):
        jc = np.stack([col[..., c].ravel() for col in cols])
        wc = w[..., c].ravel()
        jp = _project(jc, nuis[c].reshape(nuis[c].shape[0], -1), wc)
        u += (jp * wc) @ resid[..., c].ravel()
        h += (jp * wc) @ jp.T
    a, gain = _bounded_quadratic(u, h, signed)
    vec = _clip(cand, null + a, model)
    return CandidateResult(cand.name, cand.k, gain, vec)


def _score_saturation(
    model: DiagnosisModel, values: Values, ev0: Evaluation, cand: Candidate
) -> CandidateResult:
    """A clip below the declared saturation shows as a pile-up of equal values at the top."""
    m = model.data.measured_dn[model.fit_mask]
    top = float(m.max()) if m.size else 0.0
    pile = int(np.sum(m >= top - 0.5))
    null = cand.null(model.profile)
    if pile < max(20, int(2e-4 * m.size)) or top >= null[0] - 0.5:
        return CandidateResult(cand.name, 1, 0.0, null)
    trial = dict(values)
    trial[cand.name] = np.array([top])
    ev = model.evaluate(trial)
    d = ev0.chi2 - ev.chi2
    return CandidateResult(cand.name, 1, d, np.array([top]), d, np.array([top]), ev)


def fit_candidate(
    model: DiagnosisModel,
    values: Values,
    ev0: Evaluation,
    res: CandidateResult,
    n_iter: int = 5,
    deadline: float | None = None,
) -> CandidateResult:
    """Levenberg-Marquardt fit of ``res.name`` (starting at its score estimate) with the
    gains profiled; fills ``dchi2``, ``fitted``, ``evaluation`` and ``amplitude_dn``."""
    cand = CANDIDATES[res.name]
    if res.evaluation is not None and res.fitted is not None:
        res.dchi2 = ev0.chi2 - res.evaluation.chi2
        res.amplitude_dn = _amplitude(model, ev0, res.evaluation)
        return res
    prof = model.profile
    step = cand.step(prof) * 0.01
    cur = _clip(cand, res.vector.copy(), model)

    def ev_at(v: np.ndarray) -> Evaluation:
        t = dict(values)
        t[cand.name] = v
        return model.evaluate(t)

    # a zero score estimate (one-sided at the null) starts from a small step instead
    if np.allclose(cur, cand.null(prof)):
        cur = _clip(cand, cand.null(prof) + 0.3 * cand.step(prof), model)
    ev = ev_at(cur)
    lam = 1e-3
    w = model.weights
    for _ in range(n_iter):
        if deadline is not None and time.perf_counter() > deadline:
            break
        cols = []
        if cand.channelwise:
            hstep = np.where(cur + step <= cand.upper(prof), step, -step)
            diff = ev_at(cur + hstep).pred_dn - ev.pred_dn
            for i in range(cand.k):
                ci = np.zeros_like(diff)
                ci[..., i] = diff[..., i] / hstep[i]
                cols.append(ci.ravel())
        else:
            for i in range(cand.k):
                v = cur.copy()
                hi = step[i] if cur[i] + step[i] <= cand.upper(prof)[i] else -step[i]
                v[i] += hi
                cols.append(((ev_at(v).pred_dn - ev.pred_dn) / hi).ravel())
        j = np.stack(cols)
        wr = (w * (model.data.measured_dn - ev.pred_dn)).ravel()
        g = j @ wr
        hm = (j * w.ravel()) @ j.T
        improved = False
        for _try in range(4):
            a = hm + lam * np.diag(np.diag(hm) + 1e-12)
            delta = np.linalg.lstsq(a, g, rcond=None)[0]
            new = _clip(cand, cur + delta, model)
            ev_new = ev_at(new)
            if ev_new.chi2 < ev.chi2:
                gain = ev.chi2 - ev_new.chi2
                cur, ev = new, ev_new
                lam = max(lam / 5, 1e-6)
                improved = True
                break
            lam *= 10
        if not improved or gain < 0.5:
            break
    res.fitted = cur
    res.evaluation = ev
    res.dchi2 = ev0.chi2 - ev.chi2
    res.amplitude_dn = _amplitude(model, ev0, ev)
    return res


def _amplitude(model: DiagnosisModel, ev0: Evaluation, ev: Evaluation) -> float:
    d = (ev.pred_dn - ev0.pred_dn)[model.fit_mask]
    return float(np.sqrt(np.mean(d * d))) if d.size else 0.0


def select_effects(
    model: DiagnosisModel,
    candidates: list[str],
    values: Values | None = None,
    max_effects: int = 4,
    n_fit: int = 3,
    margin: float = 25.0,
    amp_floor: float = 2e-3,
    alt_tol: float | None = None,
    deadline: float | None = None,
    progress: Callable[[str], None] | None = None,
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
        How many of the best-scoring candidates get a full fit each round.
    margin
        Added to the BIC penalty k·ln(n) (Δχ² units).
    amp_floor
        The accepted effect must change the prediction by at least this fraction of the
        rms signal (below it, honest discretisation differences could be the cause).
    alt_tol
        Δχ² within which another candidate counts as an equally good explanation
        (default 2·ln(n) + 1 % of the winner's Δχ²).
    """
    vals: Values = dict(values or {})
    say = progress or (lambda _m: None)
    model.set_reference(None)
    ev = model.evaluate(vals)
    model.set_reference(ev.pred_dn)
    ev = model.evaluate(vals)
    rounds: list[Round] = []
    rejected: list[CandidateResult] = []
    log: list[str] = []
    ln_n = float(np.log(max(model.n_fit, 2)))
    sig = (ev.pred_dn - model.black)[model.fit_mask]
    signal_rms = float(np.sqrt(np.mean(sig * sig))) if sig.size else 1.0
    remaining = [c for c in candidates if c not in vals]
    while remaining and len(rounds) < max_effects:
        if deadline is not None and time.perf_counter() > deadline:
            log.append("time budget reached: selection stopped")
            break
        scores = []
        for name in list(remaining):
            try:
                res = score_candidate(model, vals, ev, CANDIDATES[name])
            except SIMULATION_ERRORS as err:
                log.append(f"{name} left out: the simulator cannot model it here ({err})")
                remaining.remove(name)
                continue
            scores.append(res)
            say(f"score {name}: Δχ² ≈ {res.score_dchi2:.1f}")
        scores.sort(key=lambda r: -(r.score_dchi2 - r.k * ln_n))
        fitted: list[CandidateResult] = []
        for res in scores[:n_fit]:
            if res.score_dchi2 - res.k * ln_n < 0.5 * margin and fitted:
                continue
            try:
                fit_candidate(model, vals, ev, res, deadline=deadline)
            except SIMULATION_ERRORS as err:
                log.append(f"{res.name} left out: fitting it failed in the simulator ({err})")
                remaining.remove(res.name)
                continue
            fitted.append(res)
            say(f"fit {res.name}: Δχ² = {res.dchi2:.1f}, amplitude {res.amplitude_dn:.2f} DN")
        ok = [
            r for r in fitted
            if r.dchi2 is not None
            and r.dchi2 > r.k * ln_n + margin
            and r.amplitude_dn > amp_floor * signal_rms
        ]
        if not ok:
            rejected.extend(fitted)
            log.append("no remaining candidate clears the criterion: " + ", ".join(
                f"{r.name} Δχ²={r.dchi2:.1f} (needs {r.k * ln_n + margin:.1f}), "
                f"amplitude {r.amplitude_dn:.2f} DN (floor {amp_floor * signal_rms:.2f})"
                for r in fitted
            ))
            break
        ok.sort(key=lambda r: -((r.dchi2 or 0.0) - r.k * ln_n))
        best = ok[0]
        assert best.fitted is not None and best.evaluation is not None and best.dchi2 is not None
        tol = alt_tol if alt_tol is not None else 2 * ln_n + 0.01 * best.dchi2
        best_bic = best.dchi2 - best.k * ln_n
        alts = [
            r for r in fitted
            if r is not best and r.dchi2 is not None and r.dchi2 - r.k * ln_n > best_bic - tol
            and r.dchi2 > r.k * ln_n + margin
        ]
        vals[best.name] = best.fitted
        threshold = best.k * ln_n + margin
        rounds.append(
            Round(best.name, best.fitted, best.dchi2, threshold, best.k, best.amplitude_dn, alts, scores, best.evaluation)
        )
        log.append(f"accepted {best.name}: Δχ² {best.dchi2:.1f} > {threshold:.1f}")
        remaining = [c for c in remaining if c != best.name and c not in {a.name for a in alts}]
        model.set_reference(best.evaluation.pred_dn)
        ev = model.evaluate(vals)
    return Selection(vals, rounds, ev, rejected, log)
