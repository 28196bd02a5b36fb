"""Weighted least-squares optimisers over a flat parameter vector (no physics in here).

Everything works on an *objective* ``evaluate(x) -> E``: ``x`` a ``(K,)`` float vector,
``E`` anything with a prediction ``pred_dn`` (any shape, e.g. ``F × R × S × C``) and its
weighted ``chi2 = Σ w·(measured − pred_dn)²``. Parameters are kept inside box bounds.
The optimisers stop gracefully when the :class:`~thintact_sdk.diagnosis.imaging.deadline.Deadline`
has expired and return the best point so far.

- :func:`levenberg_marquardt`: finite-difference Jacobians; a *channel block* of
  parameters (parameter ``j`` of the block acts on channel ``j`` only, last axis of the
  prediction) shares one evaluation for all its Jacobian columns;
- :func:`line_search`: χ² along a direction at multiples of a first estimate;
- :func:`parabola`: one coordinate refined by the vertex through three values;
- :func:`channel_polish`: per-channel local scan for channel blocks;
- :func:`bounded_quadratic` and :func:`score_test`: the linearised improvement
  max_a (2aᵀu − aᵀHa) with sign constraints (a score test on Jacobian columns).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar

import numpy as np

from thintact_sdk.diagnosis.imaging.deadline import Deadline


class Evaluated(Protocol):
    """What an objective returns: a prediction and its weighted χ²."""

    @property
    def pred_dn(self) -> np.ndarray: ...

    @property
    def chi2(self) -> float: ...


E = TypeVar("E", bound=Evaluated)
Objective = Callable[[np.ndarray], E]


@dataclass(frozen=True)
class Box:
    """Box bounds ``lower ≤ x ≤ upper`` (``(K,)`` each; ±inf where unbounded)."""

    lower: np.ndarray
    upper: np.ndarray

    def clip(self, x: np.ndarray) -> np.ndarray:
        """``x`` moved into the box."""
        return np.clip(x, self.lower, self.upper)


@dataclass(frozen=True)
class WeightedData:
    """The data an objective's χ² compares with: ``measured`` and weights ``w`` (same shape)."""

    measured: np.ndarray
    weights: np.ndarray

    def per_channel_chi2(self, pred: np.ndarray) -> np.ndarray:
        """``(C,)`` χ² of each channel (last axis)."""
        axes = tuple(range(pred.ndim - 1))
        return np.sum(self.weights * (self.measured - pred) ** 2, axis=axes)


def project_out(j: np.ndarray, d: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Remove from the rows of ``j`` (K × P) their W-weighted projection on the rows of
    ``d`` (B × P, nuisance directions); ``w`` is ``(P,)``."""
    dw = d * w
    a = dw @ d.T
    reg = 1e-12 * np.trace(a) * np.eye(len(a)) / max(len(a), 1)
    coef = np.linalg.lstsq(a + reg, dw @ j.T, rcond=None)[0]
    return j - coef.T @ d


def bounded_quadratic(u: np.ndarray, h: np.ndarray, signed: Sequence[bool]) -> tuple[np.ndarray, float]:
    """Maximise ``2aᵀu − aᵀHa`` with ``a_i ≥ 0`` where ``signed[i]`` is False (active set,
    small K). Returns ``(a, value)``."""
    k = len(u)
    free = np.ones(k, bool)
    a = np.zeros(k)
    for _ in range(k + 1):
        a = np.zeros(k)
        if free.any():
            hf = h[np.ix_(free, free)]
            a[free] = np.linalg.lstsq(hf + 1e-12 * np.trace(hf) * np.eye(int(free.sum())), u[free],
                                      rcond=None)[0]
        neg = [i for i in range(k) if free[i] and not signed[i] and a[i] < 0]
        if not neg:
            break
        free[neg] = False
    return a, float(2 * a @ u - a @ h @ a)


def score_test(
    columns: Sequence[np.ndarray],
    residual: np.ndarray,
    weights: np.ndarray,
    nuisance: Sequence[np.ndarray],
    signed: Sequence[bool],
) -> tuple[np.ndarray, float]:
    """Linearised improvement of χ² from Jacobian ``columns`` (each ``F × R × S × C``),
    with the per-channel ``nuisance`` directions (``B × F × R × S`` each) projected out.

    Returns
    -------
    step
        ``(K,)`` best parameter change (``a`` of :func:`bounded_quadratic`).
    gain
        Its Δχ² (linear estimate).
    """
    k = len(columns)
    u = np.zeros(k)
    h = np.zeros((k, k))
    for c in range(residual.shape[-1]):
        jc = np.stack([col[..., c].ravel() for col in columns])
        wc = weights[..., c].ravel()
        jp = project_out(jc, nuisance[c].reshape(nuisance[c].shape[0], -1), wc)
        u += (jp * wc) @ residual[..., c].ravel()
        h += (jp * wc) @ jp.T
    return bounded_quadratic(u, h, signed)


def line_search(
    evaluate: Objective[E],
    start: np.ndarray,
    start_ev: E,
    direction: np.ndarray,
    box: Box,
    deadline: Deadline,
    factors: Sequence[float] = (1.0, 0.5, 2.0, 4.0, 8.0),
) -> tuple[np.ndarray, E]:
    """Best of ``start + t·direction`` for ``t`` in ``factors`` (stops at the first failure
    once ``t ≥ 2``, or once the deadline has expired)."""
    cur, ev = start.copy(), start_ev
    for t in factors:
        trial = box.clip(start + t * direction)
        e = evaluate(trial)
        if e.chi2 < ev.chi2:
            cur, ev = trial, e
        elif t >= 2.0 or deadline.expired():
            break
    return cur, ev


def levenberg_marquardt(
    evaluate: Objective[E],
    x: np.ndarray,
    ev: E,
    data: WeightedData,
    box: Box,
    fd_step: np.ndarray,
    active: Sequence[int],
    deadline: Deadline,
    n_iter: int,
    channel_blocks: Sequence[Sequence[int]] = (),
) -> tuple[np.ndarray, E]:
    """Levenberg-Marquardt on the ``active`` coordinates of ``x``.

    Parameters
    ----------
    fd_step
        ``(K,)`` finite-difference steps (taken backwards where forwards leaves the box).
    channel_blocks
        Groups of coordinates whose ``j``-th member acts only on channel ``j`` of the
        prediction: one evaluation gives all their Jacobian columns.
    n_iter
        At most this many iterations; stops earlier when an iteration gains less than
        ``max(0.5, 2e-6·χ²)`` or the deadline has expired.
    """
    active = list(active)
    if not active:
        return x, ev
    blocks = [list(b) for b in channel_blocks if any(i in active for i in b)]
    in_block = {i for b in blocks for i in b}
    lam = 1e-3
    w = data.weights
    for _ in range(n_iter):
        if deadline.expired():
            break
        cols: dict[int, np.ndarray] = {}
        for block in blocks:
            idx = np.asarray(block)
            h = np.where(x[idx] + fd_step[idx] <= box.upper[idx], fd_step[idx], -fd_step[idx])
            trial = x.copy()
            trial[idx] += h
            diff = evaluate(trial).pred_dn - ev.pred_dn
            for ch, (i, hi) in enumerate(zip(block, h, strict=True)):
                if i not in active:
                    continue
                ci = np.zeros_like(diff)
                ci[..., ch] = diff[..., ch] / hi
                cols[i] = ci.ravel()
        for i in active:
            if i in in_block:
                continue
            hi = fd_step[i] if x[i] + fd_step[i] <= box.upper[i] else -fd_step[i]
            trial = x.copy()
            trial[i] += hi
            cols[i] = ((evaluate(trial).pred_dn - ev.pred_dn) / hi).ravel()
        j = np.stack([cols[i] for i in active])
        wr = (w * (data.measured - ev.pred_dn)).ravel()
        g = j @ wr
        hm = (j * w.ravel()) @ j.T
        gain = 0.0
        for _try in range(4):
            a = hm + lam * np.diag(np.diag(hm) + 1e-12)
            delta = np.linalg.lstsq(a, g, rcond=None)[0]
            new = x.copy()
            new[active] += delta
            new = box.clip(new)
            ev_new = evaluate(new)
            if ev_new.chi2 < ev.chi2:
                gain = ev.chi2 - ev_new.chi2
                x, ev = new, ev_new
                lam = max(lam / 5, 1e-6)
                break
            lam *= 10
        if gain < max(0.5, 2e-6 * ev.chi2):
            break
    return x, ev


def channel_polish(
    evaluate: Objective[E],
    x: np.ndarray,
    ev: E,
    data: WeightedData,
    box: Box,
    step: np.ndarray,
    fractions: Sequence[float] = (-0.006, -0.003, 0.003, 0.006),
) -> tuple[np.ndarray, E]:
    """Per-channel local scan for a channel block (``x[c]`` acts on channel ``c`` only):
    every trial offsets all channels at once by ``fraction·step`` and each channel keeps
    its best value (robust where χ² is not smooth in the parameter)."""
    best_val = x.copy()
    best_chi = data.per_channel_chi2(ev.pred_dn)
    for frac in fractions:
        trial = box.clip(x + frac * step)
        chi = data.per_channel_chi2(evaluate(trial).pred_dn)
        better = chi < best_chi
        best_val = np.where(better, trial, best_val)
        best_chi = np.where(better, chi, best_chi)
    if np.allclose(best_val, x):
        return x, ev
    e = evaluate(best_val)
    return (best_val, e) if e.chi2 < ev.chi2 else (x, ev)


def parabola(
    evaluate: Objective[E], x: np.ndarray, ev: E, i: int, h: float, box: Box
) -> tuple[np.ndarray, E]:
    """Refine coordinate ``i`` from χ² at ``x ± h·e_i``: the vertex of the parabola through
    the three values (moved by at most ``2h``) when it improves, else the best of the three."""
    lo, hi = x.copy(), x.copy()
    lo[i] -= h
    hi[i] += h
    lo, hi = box.clip(lo), box.clip(hi)
    e_lo = evaluate(lo)
    e_hi = evaluate(hi)
    c0, cm, cp = ev.chi2, e_lo.chi2, e_hi.chi2
    curv = cm + cp - 2 * c0
    best = min(((c0, x, ev), (cm, lo, e_lo), (cp, hi, e_hi)), key=lambda t: t[0])
    if curv > 0:
        step = float(np.clip(0.5 * h * (cm - cp) / curv, -2 * h, 2 * h))
        v = x.copy()
        v[i] += step
        v = box.clip(v)
        e = evaluate(v)
        if e.chi2 < best[0]:
            return v, e
    return best[1], best[2]
