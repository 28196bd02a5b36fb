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
#: effects scored through a cheaper proxy instead of their own signature
PROXIED = frozenset({"refraction"})


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
    refined: bool = False  # Levenberg-Marquardt done (not only the line search)
    joint: Values = field(default_factory=dict)  # refitted values of earlier effects


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
        d = ev0.chi2 - ev.chi2
        return CandidateResult(cand.name, cand.k, d, vec, d, vec, ev, refined=True)
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
            if i in cand.slow_params:
                continue
            trial = dict(values)
            v = null.copy()
            v[i] += step[i]
            trial[cand.name] = _clip(cand, v, model)
            d_i = float(trial[cand.name][i] - null[i]) or step[i]
            cols.append((model.evaluate(trial, beta=ev0.beta).pred_dn - ev0.pred_dn) / d_i)
    nuis = model.nuisance_directions(values, ev0)
    fast = [i for i in range(cand.k) if i not in cand.slow_params]
    kf = len(fast)
    u = np.zeros(kf)
    h = np.zeros((kf, kf))
    for c in range(resid.shape[3]):
        jc = np.stack([col[..., c].ravel() for col in cols])
        wc = w[..., c].ravel()
        jp = _project(jc, nuis[c].reshape(nuis[c].shape[0], -1), wc)
        u += (jp * wc) @ resid[..., c].ravel()
        h += (jp * wc) @ jp.T
    a, gain = _bounded_quadratic(u, h, tuple(signed[i] for i in fast))
    full = np.zeros(cand.k)
    full[fast] = a
    vec = _clip(cand, null + full, model)
    return CandidateResult(cand.name, cand.k, gain, vec)


def _score_saturation(
    model: DiagnosisModel, values: Values, ev0: Evaluation, cand: Candidate
) -> CandidateResult:
    """A clip below the declared saturation: try the top of the measured histogram (a
    pile-up of equal values when the clip acts after the noise) and high quantiles (when
    it acts before), keep the best and refine it by a parabola. No simulation needed."""
    m = model.data.measured_dn[model.fit_mask]
    null = cand.null(model.profile)
    if m.size == 0:
        return CandidateResult(cand.name, 1, 0.0, null)
    top = float(m.max())
    levels = {top, *(float(np.quantile(m, q)) for q in (0.9999, 0.999, 0.997, 0.99))}
    levels = {lv for lv in levels if lv < null[0] - 0.5 and lv > model.black + 1.0}
    best_d, best_v, best_ev = 0.0, null, None

    def ev_at(v: np.ndarray) -> Evaluation:
        trial = dict(values)
        trial[cand.name] = v
        return model.evaluate(trial)

    for lv in sorted(levels):
        e = ev_at(np.array([lv]))
        if ev0.chi2 - e.chi2 > best_d:
            best_d, best_v, best_ev = ev0.chi2 - e.chi2, np.array([lv]), e
    if best_ev is None:
        return CandidateResult(cand.name, 1, 0.0, null)
    if best_v[0] == top and int(np.sum(m >= top - 0.5)) >= 20:
        # a pile-up of equal values: the clip level is read off directly
        return CandidateResult(cand.name, 1, best_d, best_v, best_d, best_v, best_ev, refined=True)
    v, e = _parabola(cand, ev_at, best_v, best_ev, 0, model, h=max(2.0, 0.002 * float(best_v[0])))
    d = ev0.chi2 - e.chi2
    return CandidateResult(cand.name, 1, d, v, d, v, e, refined=True)


def fit_candidate(
    model: DiagnosisModel,
    values: Values,
    ev0: Evaluation,
    res: CandidateResult,
    n_iter: int = 6,
    deadline: float | None = None,
    refine: bool = True,
    jointly: tuple[str, ...] = (),
) -> CandidateResult:
    """Fit ``res.name`` with the gains profiled; fills ``dchi2``, ``fitted``,
    ``evaluation`` and ``amplitude_dn``.

    A line search along the score direction (0.5 to 8 times the linear estimate, which
    a large effect overshoots or undershoots) gives the start; Levenberg-Marquardt with
    finite-difference Jacobians refines the cheap parameters; parameters that need the
    simulator's slow direct path (a mask rotation) are refined last by a parabola through
    three values, when the time budget allows.
    """
    cand = CANDIDATES[res.name]
    if res.evaluation is not None and res.fitted is not None and (res.refined or not refine):
        res.dchi2 = ev0.chi2 - res.evaluation.chi2
        res.amplitude_dn = _amplitude(model, ev0, res.evaluation)
        return res
    if res.evaluation is not None and res.fitted is not None:
        cur, ev = res.fitted, res.evaluation
    else:
        cur, ev = _line_search(model, cand, values, ev0, res, deadline)
    if refine:
        joint = tuple(
            n for n in jointly if n in values and CANDIDATES[n].domain in ("optical", "post", "dn")
            and n != "saturation" and n != cand.name
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


def _line_search(
    model: DiagnosisModel,
    cand: Candidate,
    values: Values,
    ev0: Evaluation,
    res: CandidateResult,
    deadline: float | None,
) -> tuple[np.ndarray, Evaluation]:
    prof = model.profile
    null = cand.null(prof)
    active = [i for i in range(cand.k) if i not in cand.slow_params]

    def ev_at(v: np.ndarray) -> Evaluation:
        t = dict(values)
        t[cand.name] = v
        return model.evaluate(t)

    def late() -> bool:
        return deadline is not None and time.perf_counter() > deadline

    direction = res.vector - null
    if not np.any(direction):
        direction = 0.3 * cand.step(prof) * np.isin(np.arange(cand.k), active)
    cur, ev = null.copy(), ev0
    for t in (1.0, 0.5, 2.0, 4.0, 8.0):
        trial = _clip(cand, null + t * direction, model)
        e = ev_at(trial)
        if e.chi2 < ev.chi2:
            cur, ev = trial, e
        elif t >= 2.0 or late():
            break
    return cur, ev


def _refine(
    model: DiagnosisModel,
    cand: Candidate,
    values: Values,
    cur: np.ndarray,
    ev: Evaluation,
    n_iter: int,
    deadline: float | None,
    jointly: tuple[str, ...] = (),
) -> tuple[Values, Evaluation]:
    """Levenberg-Marquardt on the candidate's cheap parameters together with those of the
    effects named in ``jointly`` (accepted earlier: their values may move too), then the
    channel polish and the slow parameters; returns the new values of all of them."""

    def late() -> bool:
        return deadline is not None and time.perf_counter() > deadline

    vals = dict(values)
    vals[cand.name] = cur
    iters = n_iter + 2 if cand.channelwise and not jointly else n_iter
    vals, ev = _levenberg_marquardt(model, (cand.name, *jointly), vals, ev, iters, late)
    cur = vals[cand.name]

    def ev_at(v: np.ndarray) -> Evaluation:
        t = dict(vals)
        t[cand.name] = v
        return model.evaluate(t)

    if cand.channelwise and not late():
        cur, ev = _channel_polish(model, cand, ev_at, cur, ev)
    for i in cand.slow_params:
        if deadline is not None and deadline - time.perf_counter() < 3.5 * model.slow_sim_s:
            break
        cur, ev = _parabola(cand, ev_at, cur, ev, i, model)
    vals[cand.name] = cur
    if cand.slow_params and not np.allclose(cur[list(cand.slow_params)], 0.0):
        # one joint step over every parameter (each simulation on the slow path)
        if deadline is None or deadline - time.perf_counter() > (cand.k + 2) * model.slow_sim_s:
            vals, ev = _levenberg_marquardt(model, (cand.name,), vals, ev, 1, late, include_slow=True)
    return {n: vals[n] for n in (cand.name, *jointly)}, ev


def _levenberg_marquardt(
    model: DiagnosisModel,
    names: tuple[str, ...],
    vals: Values,
    ev: Evaluation,
    n_iter: int,
    late: Callable[[], bool],
    include_slow: bool = False,
) -> tuple[Values, Evaluation]:
    """Joint LM over the cheap parameters (all with ``include_slow``) of the effects
    ``names`` (finite differences; a channelwise effect's parameters share one simulation)."""
    prof = model.profile
    slots: list[tuple[str, int]] = []
    for n in names:
        c = CANDIDATES[n]
        slots += [(n, i) for i in range(c.k) if include_slow or i not in c.slow_params]
    if not slots:
        return vals, ev
    lam = 1e-3
    w = model.weights
    vals = dict(vals)
    for _ in range(n_iter):
        if late():
            break
        cols: list[np.ndarray] = []
        for n in names:
            c = CANDIDATES[n]
            cur = vals[n]
            step = c.step(prof) * 0.01
            upper = c.upper(prof)
            act = [i for i in range(c.k) if include_slow or i not in c.slow_params]
            if c.channelwise:
                hstep = np.where(cur + step <= upper, step, -step)
                trial = dict(vals)
                trial[n] = cur + hstep
                diff = model.evaluate(trial).pred_dn - ev.pred_dn
                for i in act:
                    ci = np.zeros_like(diff)
                    ci[..., i] = diff[..., i] / hstep[i]
                    cols.append(ci.ravel())
            else:
                for i in act:
                    v = cur.copy()
                    hi = step[i] if cur[i] + step[i] <= upper[i] else -step[i]
                    v[i] += hi
                    trial = dict(vals)
                    trial[n] = v
                    cols.append(((model.evaluate(trial).pred_dn - ev.pred_dn) / hi).ravel())
        j = np.stack(cols)
        wr = (w * (model.data.measured_dn - ev.pred_dn)).ravel()
        g = j @ wr
        hm = (j * w.ravel()) @ j.T
        gain = 0.0
        for _try in range(4):
            a = hm + lam * np.diag(np.diag(hm) + 1e-12)
            delta = np.linalg.lstsq(a, g, rcond=None)[0]
            new = dict(vals)
            for n in names:
                new[n] = vals[n].copy()
            for (n, i), dv in zip(slots, delta, strict=True):
                new[n][i] += dv
            for n in names:
                new[n] = _clip(CANDIDATES[n], new[n], model)
            ev_new = model.evaluate(new)
            if ev_new.chi2 < ev.chi2:
                gain = ev.chi2 - ev_new.chi2
                vals, ev = new, ev_new
                lam = max(lam / 5, 1e-6)
                break
            lam *= 10
        if gain < max(0.5, 2e-6 * ev.chi2):
            break
    return vals, ev


def _channel_polish(
    model: DiagnosisModel,
    cand: Candidate,
    ev_at: Callable[[np.ndarray], Evaluation],
    cur: np.ndarray,
    ev: Evaluation,
) -> tuple[np.ndarray, Evaluation]:
    """Per-channel local scan for channelwise parameters: χ² of each channel depends only
    on its own parameter, so every trial offsets all channels at once and each channel
    keeps its best value (robust where χ² is not smooth in the parameter)."""
    w = model.weights
    step = cand.step(model.profile)

    def per_channel(e: Evaluation) -> np.ndarray:
        return np.sum(w * (model.data.measured_dn - e.pred_dn) ** 2, axis=(0, 1, 2))

    best_val = cur.copy()
    best_chi = per_channel(ev)
    for frac in (-0.006, -0.003, 0.003, 0.006):
        trial = _clip(cand, cur + frac * step, model)
        chi = per_channel(ev_at(trial))
        better = chi < best_chi
        best_val = np.where(better, trial, best_val)
        best_chi = np.where(better, chi, best_chi)
    if np.allclose(best_val, cur):
        return cur, ev
    e = ev_at(best_val)
    return (best_val, e) if e.chi2 < ev.chi2 else (cur, ev)


def _parabola(
    cand: Candidate,
    ev_at: Callable[[np.ndarray], Evaluation],
    cur: np.ndarray,
    ev: Evaluation,
    i: int,
    model: DiagnosisModel,
    h: float | None = None,
) -> tuple[np.ndarray, Evaluation]:
    """Refine parameter ``i`` from χ² at cur ± h (a parabola's vertex; h defaults to the
    candidate's typical step)."""
    h = float(cand.step(model.profile)[i]) if h is None else h
    lo, hi = cur.copy(), cur.copy()
    lo[i] -= h
    hi[i] += h
    t0 = time.perf_counter()
    e_lo = ev_at(_clip(cand, lo, model))
    model.slow_sim_s = time.perf_counter() - t0
    e_hi = ev_at(_clip(cand, hi, model))
    c0, cm, cp = ev.chi2, e_lo.chi2, e_hi.chi2
    curv = cm + cp - 2 * c0
    best = min(((c0, cur, ev), (cm, lo, e_lo), (cp, hi, e_hi)), key=lambda x: x[0])
    if curv > 0:
        x = float(np.clip(0.5 * h * (cm - cp) / curv, -2 * h, 2 * h))
        v = cur.copy()
        v[i] += x
        v = _clip(cand, v, model)
        e = ev_at(v)
        if e.chi2 < best[0]:
            return v, e
    return best[1], best[2]


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
        How many of the best candidates after the line search get a full fit each round.
    margin
        Added to the BIC penalty k·ln(n) (Δχ² units).
    amp_floor
        The accepted effect must change the prediction by at least this fraction of the
        rms signal (below it, honest discretisation differences could be the cause).
    alt_tol
        Δχ² within which another candidate counts as an equally good explanation
        (default 2·ln(n) + 0.2 % of the winner's Δχ²).
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
    accepted_names: tuple[str, ...] = ()
    while remaining and len(rounds) < max_effects:
        if deadline is not None and time.perf_counter() > deadline:
            log.append("time budget reached: selection stopped")
            break
        scores = []
        for name in list(remaining):
            if name in PROXIED:
                continue
            if deadline is not None and time.perf_counter() > deadline:
                break
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
        for res in scores:
            if res.score_dchi2 - res.k * ln_n < 0.5 * margin and fitted:
                continue
            if fitted and deadline is not None and time.perf_counter() > deadline:
                break
            try:
                fit_candidate(model, vals, ev, res, deadline=deadline, refine=False)
            except SIMULATION_ERRORS as err:
                log.append(f"{res.name} left out: fitting it failed in the simulator ({err})")
                remaining.remove(res.name)
                continue
            fitted.append(res)
            say(f"line search {res.name}: Δχ² = {res.dchi2:.1f}")
        fitted.sort(key=lambda r: -((r.dchi2 or 0.0) - r.k * ln_n))
        for res in fitted[:n_fit]:
            if (res.dchi2 or 0.0) - res.k * ln_n < 0.5 * margin:
                continue
            # one fit may use at most 40 % of the time left, so later rounds still happen
            # (a fit on the simulator's slow path needs every second it can get)
            fit_deadline = deadline
            cand = CANDIDATES[res.name]
            if deadline is not None and not (cand.slow_params or cand.costly):
                now = time.perf_counter()
                fit_deadline = now + 0.4 * max(deadline - now, 0.0)
            try:
                fit_candidate(model, vals, ev, res, deadline=fit_deadline, jointly=accepted_names)
            except SIMULATION_ERRORS as err:
                log.append(f"{res.name} left out: fitting it failed in the simulator ({err})")
                remaining.remove(res.name)
                fitted.remove(res)
                continue
            say(f"fit {res.name}: Δχ² = {res.dchi2:.1f}, amplitude {res.amplitude_dn:.2f} DN")
        _refraction_proxy(model, vals, ev, fitted, remaining, deadline, say)
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
        tol = alt_tol if alt_tol is not None else 2 * ln_n + 0.002 * best.dchi2
        best_bic = best.dchi2 - best.k * ln_n
        alts = [
            r for r in fitted
            if r is not best and r.dchi2 is not None and r.dchi2 - r.k * ln_n > best_bic - tol
            and r.dchi2 > r.k * ln_n + margin
        ]
        vals.update(best.joint)
        for rnd in rounds:
            if rnd.name in best.joint:
                rnd.vector = best.joint[rnd.name]
        vals[best.name] = best.fitted
        accepted_names = (*accepted_names, best.name)
        threshold = best.k * ln_n + margin
        rounds.append(
            Round(best.name, best.fitted, best.dchi2, threshold, best.k, best.amplitude_dn, alts, scores, best.evaluation)
        )
        log.append(f"accepted {best.name}: Δχ² {best.dchi2:.1f} > {threshold:.1f}")
        remaining = [c for c in remaining if c != best.name and c not in {a.name for a in alts}]
        model.set_reference(best.evaluation.pred_dn)
        ev = model.evaluate(vals)
    return Selection(vals, rounds, ev, rejected, log)


def _refraction_proxy(
    model: DiagnosisModel,
    vals: Values,
    ev0: Evaluation,
    fitted: list[CandidateResult],
    remaining: list[str],
    deadline: float | None,
    say: Callable[[str], None],
) -> None:
    """Refraction needs the simulator's slow path, but near the axis it acts like a
    shorter scene gap (z/n at the same mask-to-sensor gap d): when the geometry fit
    shortens z/d, try n = (z/d)_profile / (z/d)_fit and refine it by a parabola (adds a
    fitted result to ``fitted``)."""
    if "refraction" not in remaining:
        return
    geo = next((r for r in fitted if r.name == "geometry" and r.fitted is not None), None)
    g = model.profile.geometry
    ratio0 = g.scene_to_mask_mm / g.mask_to_sensor_mm
    if geo is None or geo.fitted is None:
        return
    ratio = float(geo.fitted[0] / geo.fitted[1])
    if ratio > 0.995 * ratio0:
        return
    if deadline is not None and deadline - time.perf_counter() < 4.5 * model.slow_sim_s:
        return
    cand = CANDIDATES["refraction"]
    n0 = _clip(cand, np.array([ratio0 / ratio]), model)

    def ev_at(v: np.ndarray) -> Evaluation:
        t = dict(vals)
        t["refraction"] = v
        return model.evaluate(t)

    try:
        t0 = time.perf_counter()
        ev = ev_at(n0)
        model.slow_sim_s = time.perf_counter() - t0
        cur, ev = _parabola(cand, ev_at, n0, ev, 0, model, h=0.02 * float(n0[0]))
        if deadline is None or deadline - time.perf_counter() > 3.5 * model.slow_sim_s:
            cur, ev = _parabola(cand, ev_at, cur, ev, 0, model, h=0.004 * float(cur[0]))
    except SIMULATION_ERRORS:
        remaining.remove("refraction")
        return
    res = CandidateResult("refraction", 1, 0.0, cur, ev0.chi2 - ev.chi2, cur, ev)
    res.refined = True
    res.amplitude_dn = _amplitude(model, ev0, ev)
    fitted.append(res)
    say(f"refraction (from the geometry fit): n = {float(cur[0]):.3f}, Δχ² = {res.dchi2:.1f}")
