"""System matrices from slit scans: the paper's Algorithms 1-3 (§D) and a least-squares variant.

For one channel, horizontal slit ``i`` (scene ``X = e_i rᵢᵀ``) measures::

    Y_hi = p_oi (Qo rᵢ)ᵀ + p_ci (Qc rᵢ)ᵀ       (paper: rᵢ = 1, Qo·1 = q_o)

and vertical slit ``j`` (``X = c_j e_jᵀ``) measures ``Y_vjᵀ = q_oj (Po c_j)ᵀ + q_cj (Pc c_j)ᵀ``.

``method="paper"`` is Algorithm 1 exactly: project on ``q_o``, deflate, project on ``q_c``.
That is the least-squares fit only when ``q_o ⊥ q_c``; for a GA or random mask they are not
orthogonal and the deflation leaves a bias. ``method="lsq"`` (default) solves each slit's
two columns jointly (2 × 2 normal equations), i.e. alternating least squares on the same data
with the same initial estimates (Algorithm 2) and the same refinement loop (Algorithm 3).

The T2S factorisation is ambiguous: ``(P·a, Q/a)`` per term, and more generally any
invertible 2 × 2 mixing of the (open, coding) pairs leaves every product unchanged. The
scale is fixed the paper's way (equal Frobenius norms of P and Q per term); the mixing is
fixed by :mod:`thintact_sdk.calibration.gauge` (open term = the smoothest one).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from thintact_sdk.calibration.channel_matrices import ChannelMatrices
from thintact_sdk.calibration.collect import SlitCollection
from thintact_sdk.calibration.gauge import balance_frobenius, fix_gauge
from thintact_sdk.calibration.slits import ChannelSlits, SlitStack
from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.reconstruction.t2s import SystemMatrices

Method = Literal["lsq", "paper"]


@dataclass
class SolveReport:
    """How a channel's solve went.

    Attributes
    ----------
    iterations
        Refinement iterations run (Algorithm 3).
    converged
        True when the relative change fell below the tolerance before ``max_iter``.
    residual_history
        Relative residual ``Σ‖Y − model‖² / Σ‖Y‖²`` over all slits after each iteration
        (DN² over DN²).
    change_history
        Relative change of the matrices at each iteration.
    """

    iterations: int
    converged: bool
    residual_history: list[float] = field(default_factory=list)
    change_history: list[float] = field(default_factory=list)

    @property
    def final_residual(self) -> float:
        return self.residual_history[-1] if self.residual_history else float("nan")


def _fit_columns(
    stack: SlitStack, u: np.ndarray, w: np.ndarray, n_out: int, method: Method
) -> tuple[np.ndarray, np.ndarray, float]:
    """Algorithm 1 (``get_Po_Pc_given_qo_qc``) for every slit of ``stack``.

    Parameters
    ----------
    stack
        Slits oriented so that ``Y_i ≈ a_i u_iᵀ + b_i w_iᵀ``.
    u, w
        ``n × B`` known vectors per slit.
    n_out
        Number of columns of the result (scene rows N or columns M); slits with the same
        index are combined (least squares over all of them).
    method
        ``"paper"`` (sequential projections) or ``"lsq"`` (joint 2 × 2 least squares).

    Returns
    -------
    (A, B, residual)
        ``out_len × n_out`` matrices of the columns ``a``, ``b`` and the summed squared
        residual of the fit in DN².
    """
    yu = stack.times(u)  # n × A
    yw = stack.times(w)
    uu = np.einsum("nb,nb->n", u, u)
    ww = np.einsum("nb,nb->n", w, w)
    uw = np.einsum("nb,nb->n", u, w)
    if np.any(uu <= 0) or np.any(ww <= 0):
        raise CalibrationError("degenerate slit model: a known vector is zero (check the slit scenes)")
    idx = stack.index
    a_cols = np.zeros((n_out, stack.out_len))
    b_cols = np.zeros((n_out, stack.out_len))
    if method == "paper":
        a = yu / uu[:, None]
        b = (yw - a * uw[:, None]) / ww[:, None]
        counts = np.bincount(idx, minlength=n_out).astype(np.float64)
        np.add.at(a_cols, idx, a)
        np.add.at(b_cols, idx, b)
        seen = counts > 0
        a_cols[seen] /= counts[seen, None]
        b_cols[seen] /= counts[seen, None]
    else:
        gram = np.zeros((n_out, 2, 2))
        rhs = np.zeros((n_out, 2, stack.out_len))
        np.add.at(gram, idx, np.stack([np.stack([uu, uw], -1), np.stack([uw, ww], -1)], -2))
        np.add.at(rhs, idx, np.stack([yu, yw], 1))
        seen = np.bincount(idx, minlength=n_out) > 0
        sol = np.linalg.solve(gram[seen], rhs[seen])  # m × 2 × A
        a_cols[seen] = sol[:, 0]
        b_cols[seen] = sol[:, 1]
    a = a_cols[idx]
    b = b_cols[idx]
    resid = (
        stack.energy
        - 2.0 * (np.einsum("na,na->n", a, yu) + np.einsum("na,na->n", b, yw))
        + np.einsum("na,na->n", a, a) * uu
        + 2.0 * np.einsum("na,na->n", a, b) * uw
        + np.einsum("na,na->n", b, b) * ww
    )
    return a_cols.T, b_cols.T, float(np.sum(resid))


def _known_vectors(m_open: np.ndarray, m_code: np.ndarray, profile: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``u_i = M_o rᵢ``, ``w_i = M_c rᵢ`` for every slit profile ``rᵢ`` (rows of ``profile``)."""
    return profile @ m_open.T, profile @ m_code.T


def _top_right_singular_vector(stack: SlitStack, pos: int, a: np.ndarray, u: np.ndarray) -> np.ndarray:
    """First right singular vector of ``Y_pos − a uᵀ`` (Algorithm 2), from the factors."""
    left = np.concatenate([stack.left[pos], -a[:, None]], axis=1)
    right = np.concatenate([stack.right[pos], u[:, None]], axis=1)
    ql, rl = np.linalg.qr(left)
    qr_, rr = np.linalg.qr(right)
    _, _, vt = np.linalg.svd(rl @ rr.T)
    v = qr_ @ vt[0]
    return v if v.sum() >= 0 else -v


def initial_estimates(slits: ChannelSlits, method: Method = "lsq") -> ChannelMatrices:
    """Algorithm 2: ``q_o = 1``, ``q_c`` from the strongest horizontal slit, then Algorithm 1.

    The paper takes the centre slit ``Y_h[N/2]``; the strongest one is the same slit on a
    centred device and stays well conditioned when the sensing area is off-centre.
    """
    h, v = slits.horizontal, slits.vertical
    s_len = h.in_len
    ones = np.ones((h.count, s_len))
    # Algorithm 2 with q_o = 1: p_oi = Y_hi 1 / S (the paper's "/N" is the length of q_o)
    yu = h.times(ones)
    a_init = yu / s_len
    pos = h.largest()
    qc = _top_right_singular_vector(h, pos, a_init[pos], ones[pos])
    # a slit profile rᵢ = 1 gives Qo rᵢ = q_o: scale the per-slit vectors by the profile sums
    scale = h.profile.sum(axis=1) / h.profile.shape[1]
    u = ones * scale[:, None]
    w = np.tile(qc, (h.count, 1)) * scale[:, None]
    po, pc, _ = _fit_columns(h, u, w, slits.n_rows, method)
    uq, wq = _known_vectors(po, pc, v.profile)
    qo, qcm, _ = _fit_columns(v, uq, wq, slits.n_cols, method)
    return ChannelMatrices(po, qo, pc, qcm)


def refine(
    slits: ChannelSlits,
    init: ChannelMatrices,
    method: Method = "lsq",
    max_iter: int = 50,
    tol: float = 1e-7,
    gauge: bool = True,
) -> tuple[ChannelMatrices, SolveReport]:
    """Algorithm 3: alternate Algorithm 1 on horizontal and vertical slits until converged.

    Parameters
    ----------
    slits
        The channel's compressed slits.
    init
        Initial estimates (Algorithm 2).
    method
        ``"lsq"`` (joint least squares per slit) or ``"paper"`` (Algorithm 1 verbatim).
    max_iter
        Maximum number of refinement iterations.
    tol
        Stop when the relative change of the fit residual and of the (gauge-fixed)
        matrices both fall below ``tol``.
    gauge
        Fix the open/coding mixing after every iteration (only with ``"lsq"``, which is
        invariant to it); the Frobenius balance of Algorithm 3 is always applied.
    """
    h, v = slits.horizontal, slits.vertical
    total = float(h.energy.sum() + v.energy.sum())
    if total <= 0:
        raise CalibrationError("the slit images hold no signal (all zero after dark subtraction)")
    cur = init.copy()
    report = SolveReport(iterations=0, converged=False)
    prev_res = None
    for it in range(1, max_iter + 1):
        u, w = _known_vectors(cur.Qo, cur.Qc, h.profile)
        po, pc, res_h = _fit_columns(h, u, w, slits.n_rows, method)
        uq, wq = _known_vectors(po, pc, v.profile)
        qo, qc, res_v = _fit_columns(v, uq, wq, slits.n_cols, method)
        new = balance_frobenius(ChannelMatrices(po, qo, pc, qc))
        if gauge and method == "lsq":
            new = fix_gauge(new)
        res = (res_h + res_v) / total
        change = _relative_change(cur, new)
        report.residual_history.append(res)
        report.change_history.append(change)
        report.iterations = it
        cur = new
        res_change = abs(res - prev_res) / max(res, 1e-300) if prev_res is not None else np.inf
        prev_res = res
        if change < tol or (res_change < tol and change < np.sqrt(tol)):
            report.converged = True
            break
    return cur, report


def _relative_change(a: ChannelMatrices, b: ChannelMatrices) -> float:
    num = sum(float(np.sum((x - y) ** 2)) for x, y in zip(_arrays(a), _arrays(b), strict=True))
    den = sum(float(np.sum(y**2)) for y in _arrays(b))
    return float(np.sqrt(num / max(den, 1e-300)))


def _arrays(m: ChannelMatrices) -> tuple[np.ndarray, ...]:
    return (m.Po, m.Qo, m.Pc, m.Qc)


def solve_channel(
    slits: ChannelSlits,
    method: Method = "lsq",
    max_iter: int = 50,
    tol: float = 1e-7,
) -> tuple[ChannelMatrices, SolveReport]:
    """Algorithms 2 then 3 for one channel; raises :class:`CalibrationError` on missing slits."""
    problems = slits.check_complete()
    if problems:
        raise CalibrationError("cannot solve the system matrices: " + "; ".join(problems))
    init = initial_estimates(slits, method)
    mats, report = refine(slits, init, method=method, max_iter=max_iter, tol=tol)
    if method == "lsq":
        mats = fix_gauge(mats)
    return mats, report


def solve_collection(collection: SlitCollection, profile: Profile, method: Method = "lsq",
                     max_iter: int = 50, tol: float = 1e-7
                     ) -> tuple[SystemMatrices, list[SolveReport]]:
    """Algorithms 2-3 for every channel of ``collection``: the unit's system matrices (DN per
    display unit at the collection's reference exposure) and each channel's solve report."""
    mats: list[ChannelMatrices] = []
    reports: list[SolveReport] = []
    for slits in collection.channels:
        m, rep = solve_channel(slits, method=method, max_iter=max_iter, tol=tol)
        mats.append(m)
        reports.append(rep)
    sm = SystemMatrices(
        np.stack([m.Po for m in mats]), np.stack([m.Qo for m in mats]),
        np.stack([m.Pc for m in mats]), np.stack([m.Qc for m in mats]),
        {
            "source": "calibration",
            "profile": profile.name,
            "profile_hash": profile.content_hash(),
            "method": method,
            "gauge": "open term smoothest; ‖P‖_F = ‖Q‖_F per term",
            "exposure_us": collection.exposure_us,
        },
    )
    return sm, reports
