"""The ThinTact non-iterative decoder (paper §B): joint filter, subtraction, closed-form Tikhonov.

``Yc = Y − Φs ⊙ IDCT(Φf ⊙ DCT(Y))``, then per channel
``X̂ = V_P [(Σ_P U_Pᵀ Yc U_Q Σ_Q) ./ (σ_P σ_Qᵀ + τ)] V_Qᵀ``.

Fast path (exact when the filter has that structure, which ``train_joint_filter`` can impose):
when Φf is zero outside its lowest ``kr × ks`` DCT frequencies and ``Φs = Σ_j u_j v_jᵀ`` has a
small rank r, the filter folds into the Tikhonov products::

    Σ_P U_Pᵀ Yc U_Q Σ_Q = L Y Rt − Σ_j L_j [Φf_k ⊙ (D_k Y E_kᵀ)] R_j

with ``L = Σ_P U_Pᵀ``, ``Rt = U_Q Σ_Q``, ``D_k``/``E_k`` the first kr/ks rows of the DCT
matrices, ``L_j = L diag(u_j) D_kᵀ`` and ``R_j = E_k diag(v_j) Rt``. ``[L; D_k] Y`` is one
product, so a frame costs one big GEMM, one medium GEMM and small ones, all channels batched.
The black level folds in as a precomputed constant, so raw DN go straight in.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from thintact_sdk.errors import InvalidValueError
from thintact_sdk.reconstruction.dct import SeparableDCT, dct_matrix
from thintact_sdk.reconstruction.decoders.backend import ArrayBackend, synthesis_macs
from thintact_sdk.reconstruction.decoders.closed_form_base import ClosedFormDecoder
from thintact_sdk.reconstruction.decoders.modes import (
    DEFAULT_MODE_RTOL,
    TauSpec,
    channel_taus,
    kept_mode_counts,
    representative_tau,
)
from thintact_sdk.reconstruction.joint_filter import JointFilter, joint_filter_open
from thintact_sdk.reconstruction.t2s import SystemMatrices
from thintact_sdk.reconstruction.tikhonov import TikhonovSolver


def low_rank_factors(phi_s: np.ndarray, max_rank: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, float]:
    """Randomised SVD of one ``R × S`` Φs with ``max_rank + 4`` probes.

    Returns ``(us: R × k, vt: k × S, residual)`` with ``Φs ≈ us @ vt`` (singular values folded
    into ``us``) and ``residual = ‖Φs − us vt‖_F / ‖Φs‖_F`` of the full probe space (0 up to
    rounding when rank(Φs) ≤ max_rank + 4).
    """
    a = np.asarray(phi_s, np.float64)
    omega = np.random.default_rng(seed).standard_normal((a.shape[1], max_rank + 4))
    q, _ = np.linalg.qr(a @ omega)
    b = q.T @ a
    norm = float(np.linalg.norm(a))
    residual = float(np.linalg.norm(a - q @ b)) / norm if norm > 0 else 0.0
    ub, sb, vt = np.linalg.svd(b, full_matrices=False)
    return (q @ ub) * sb, vt, residual


def filter_structure(
    jf: JointFilter, max_rank: int = 8, tol: float = 1e-6
) -> tuple[int, int, int, list[tuple[np.ndarray, np.ndarray]]]:
    """``(kr, ks, rank, factors)``: Φf's support block, Φs's numerical rank (all channels; a value
    above ``max_rank`` means "not low-rank") and per channel the factors ``(us, vt)`` of Φs."""
    nz = np.abs(jf.phi_f) > 0
    rows = np.flatnonzero(nz.any(axis=(0, 2)))
    cols = np.flatnonzero(nz.any(axis=(0, 1)))
    kr = int(rows[-1]) + 1 if rows.size else 1
    ks = int(cols[-1]) + 1 if cols.size else 1
    rank = 0
    factors = []
    for c in range(jf.channels):
        us, vt, residual = low_rank_factors(jf.phi_s[c], max_rank)
        sv = np.linalg.norm(us, axis=0)
        rank_c = int(np.sum(sv > tol * sv[0])) if sv[0] > 0 else 0
        if residual > tol:
            rank_c = max_rank + 1
        rank = max(rank, rank_c)
        factors.append((us, vt))
    return kr, ks, max(rank, 1), factors


class NonIterativeDecoder(ClosedFormDecoder):
    """Joint-filter + closed-form decoder.

    Parameters
    ----------
    system_matrices
        T2S matrices (DN per display unit); only ``Pc``, ``Qc`` are used at run time.
    joint_filter
        Trained Φf, Φs; ``None`` skips the filter (``Yc = Y``).
    tau
        Tikhonov weight τ (DN² units of the matrices).
    backend
        :class:`ArrayBackend` (default numpy float32).
    fold
        ``"auto"``: fold the filter when its structure allows it exactly (``kr·ks`` ≤ a quarter of
        ``R·S`` and rank(Φs) ≤ ``max_rank``), else apply it with DCTs. ``"never"``: always DCTs.
        ``"approx"``: fold after truncating Φs to ``max_rank`` and Φf to ``block`` (an
        approximation whose cost must be measured).
    max_rank, block
        Limits for folding (``block`` = ``(kr, ks)``, only for ``"approx"``).
    mode_rtol
        Tikhonov modes whose filter factor stays below this are not computed
        (:func:`~thintact_sdk.reconstruction.decoders.modes.kept_mode_counts`; 0 keeps all).
        :attr:`kept_modes` says how many of P's and Q's were kept.
    """

    name = "thintact-noniterative"

    def __init__(
        self,
        system_matrices: SystemMatrices,
        joint_filter: JointFilter | None,
        tau: TauSpec,
        backend: ArrayBackend | None = None,
        fold: str = "auto",
        max_rank: int = 8,
        block: tuple[int, int] | None = None,
        mode_rtol: float = DEFAULT_MODE_RTOL,
    ) -> None:
        if fold not in ("auto", "never", "approx"):
            raise InvalidValueError(f"fold must be 'auto', 'never' or 'approx', got {fold!r}")
        self.xp = backend or ArrayBackend("numpy")
        sm = system_matrices
        self.channel_tau = channel_taus(tau, sm.channels)
        self.tau = representative_tau(self.channel_tau)
        self.mode_rtol = float(mode_rtol)
        self.channels = sm.channels
        self.sensor_shape = sm.sensor_shape
        self.scene_shape = sm.scene_shape
        solvers = [TikhonovSolver(sm.Pc[c], sm.Qc[c], float(self.channel_tau[c]), np.float64)
                   for c in range(sm.channels)]
        left = np.stack([s.left for s in solvers])  # C × kP × R
        right = np.stack([s.right for s in solvers])  # C × S × kQ
        self._sp = np.stack([s.singular_values_p for s in solvers])  # C × kP
        self._sq = np.stack([s.singular_values_q for s in solvers])  # C × kQ
        self.folded = False
        self.filter_info: dict[str, Any] = {"filter": joint_filter is not None}
        self._jf = joint_filter
        self._full: dict[str, np.ndarray] = {"left": left, "right": right,
                                             "vp": np.stack([s.vp for s in solvers]),
                                             "vqt": np.stack([s.vqt for s in solvers])}
        if joint_filter is not None:
            kr, ks, rank, factors = filter_structure(joint_filter, max_rank)
            r, s = self.sensor_shape
            foldable = kr * ks <= (r * s) // 4 and rank <= max_rank
            if fold == "approx":
                kr, ks = block or (kr, ks)
                rank = min(rank, max_rank)
                foldable = True
            self.filter_info.update(kr=kr, ks=ks, phi_s_rank=rank)
            if fold != "never" and foldable:
                self.folded = True
                self._full["dk"], self._full["lcat"], self._full["rcat"], self._phif = self._fold(
                    left, right, joint_filter, kr, ks, rank, factors)
                self._ek_t = self.xp.asarray(dct_matrix(s)[:ks].T, gemm=True)  # S × ks
                self.kr, self.rank = kr, rank
            elif self.xp.name == "torch":
                self._dct = SeparableDCT((r, s), to_backend=self.xp.asarray)
                self._pf = self.xp.asarray(joint_filter.phi_f)
                self._ps = self.xp.asarray(joint_filter.phi_s)
        self.filter_info["folded"] = self.folded
        self.kept_modes = (0, 0)
        self._place(*kept_mode_counts(self._sp, self._sq, self.channel_tau, self.mode_rtol))

    def _place(self, kp: int, kq: int) -> None:
        """Put the operators of the leading ``kp × kq`` modes on the backend (contiguous)."""
        xp, full = self.xp, self._full
        self.kept_modes = (kp, kq)
        self.k_p = kp
        big_left = full["left"][:, :kp]
        if self.folded:
            c, r = self.channels, self.sensor_shape[0]
            dk = full["dk"]
            big_left = np.concatenate([big_left, np.broadcast_to(dk, (c, dk.shape[0], r))], axis=1)
            rcat = full["rcat"]
            ks = rcat.shape[1]
            self._lcat = xp.asarray(full["lcat"][:, :kp])  # C × kp × (rank·kr)
            self._rcat = xp.asarray(rcat.reshape(c, ks, self.rank, -1)[..., :kq].reshape(c, ks, -1))
        self._big_left = xp.asarray(big_left, gemm=True)
        self._right = xp.asarray(full["right"][..., :kq], gemm=True)
        self._sig2 = np.einsum("ci,cj->cij", self._sp[:, :kp] ** 2, self._sq[:, :kq] ** 2)
        self._inv_denom = xp.asarray(1.0 / (self._sig2 + self.channel_tau[:, None, None]))
        self._vp = xp.asarray(full["vp"][..., :kp], gemm=True)
        self._vqt = xp.asarray(full["vqt"][:, :kq], gemm=True)
        self._unit_core: Any = None
        self._black_term: tuple[float, Any] | None = None  # (black level, black · unit core)

    def set_tau(self, tau: TauSpec) -> None:
        """Change τ (one value, or one per channel) without recomputing the SVDs (the modes
        kept follow the new τ)."""
        self.channel_tau = channel_taus(tau, self.channels)
        self.tau = representative_tau(self.channel_tau)
        kept = kept_mode_counts(self._sp, self._sq, self.channel_tau, self.mode_rtol)
        if kept != self.kept_modes:
            self._place(*kept)
        else:
            self._inv_denom = self.xp.asarray(1.0 / (self._sig2 + self.channel_tau[:, None, None]))

    def gemm_flops(self) -> int:
        """Floating-point operations of the matrix products of one frame, all channels."""
        c, (r, s), (n, m) = self.channels, self.sensor_shape, self.scene_shape
        kp, kq = self.kept_modes
        rows = kp + (self.kr if self.folded else 0)
        flops = rows * r * s + kp * s * kq + synthesis_macs(n, kp, kq, m)
        if self.folded:
            ks = self._ek_t.shape[-1]
            flops += self.kr * s * ks + self.kr * ks * self.rank * kq + kp * self.rank * self.kr * kq
        return 2 * c * flops

    # -- precomputation ----------------------------------------------------------------
    def _fold(
        self, left: np.ndarray, right: np.ndarray, jf: JointFilter, kr: int, ks: int, rank: int,
        factors: list[tuple[np.ndarray, np.ndarray]],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, Any]:
        """``(D_k, L_cat, R_cat, Φf block)``: float64 numpy except Φf (on the backend)."""
        r, s = self.sensor_shape
        dk = dct_matrix(r)[:kr]  # kr × R
        ek = dct_matrix(s)[:ks]  # ks × S
        lcats, rcats = [], []
        for c in range(self.channels):
            us, vt = factors[c]
            ls, rs = [], []
            for j in range(rank):
                uj = us[:, j]
                ls.append((left[c] * uj[None, :]) @ dk.T)  # kP × kr
                rs.append((ek * vt[j][None, :]) @ right[c])  # ks × kQ
            lcats.append(np.concatenate(ls, axis=1))  # kP × (rank·kr)
            rcats.append(np.concatenate(rs, axis=1))  # ks × (rank·kQ)
        phif = jf.phi_f[:, :kr, :ks].astype(np.float64)
        return dk, np.stack(lcats), np.stack(rcats), self.xp.asarray(phif)

    # -- the per-frame work ------------------------------------------------------------
    def _core(self, y: Any) -> Any:
        """``Σ_P U_Pᵀ Yc U_Q Σ_Q`` for channel-first ``y`` (``C × R × S``, GEMM precision)."""
        xp = self.xp
        t = self._big_left @ y  # C × (kP [+ kr]) × S
        core = xp.cast(t[:, : self.k_p] @ self._right, gemm=False)  # C × kP × kQ
        if self.folded:
            z = xp.cast(t[:, self.k_p :] @ self._ek_t, gemm=False)  # C × kr × ks
            w = self._phif * z
            tw = w @ self._rcat  # C × kr × (rank·kQ)
            c, kr, _ = tw.shape
            k_q = core.shape[-1]
            stacked = xp.contiguous(xp.permute(tw.reshape(c, kr, self.rank, k_q), (0, 2, 1, 3)))
            core = core - self._lcat @ stacked.reshape(c, self.rank * kr, k_q)
        return core

    def _filter_unfolded(self, y_np: np.ndarray) -> np.ndarray:
        assert self._jf is not None
        return y_np - joint_filter_open(self._jf.phi_s, self._jf.phi_f, y_np, SeparableDCT(self.sensor_shape))

    def _solve(self, y_cf: Any, black_dn: float = 0.0) -> np.ndarray:
        xp = self.xp
        if self._jf is not None and not self.folded:
            if xp.name == "numpy":
                y_cf = xp.asarray(self._filter_unfolded(np.asarray(y_cf, np.float64)), gemm=True)
            else:
                y32 = xp.cast(y_cf, gemm=False)
                f = joint_filter_open(self._ps, self._pf, y32, self._dct)
                y_cf = xp.cast(y32 - f, gemm=True)
        core = self._core(y_cf)  # this frame's own array: updated in place
        if black_dn:
            cached = self._black_term
            if cached is None or cached[0] != black_dn:  # one full-size pass per frame, not two
                cached = self._black_term = (black_dn, black_dn * self._black_core())
            core -= cached[1]
        core *= self._inv_denom
        return xp.synthesise(self._vp, core, self._vqt)

    def _black_core(self) -> Any:
        if self._unit_core is None:
            ones = np.ones((self.channels, *self.sensor_shape), np.float32)
            xp = self.xp
            y = xp.asarray(ones, gemm=True)
            if self._jf is not None and not self.folded:
                if xp.name == "numpy":
                    y = xp.asarray(self._filter_unfolded(ones.astype(np.float64)), gemm=True)
                else:
                    f = joint_filter_open(self._ps, self._pf, xp.cast(y, False), self._dct)
                    y = xp.cast(xp.cast(y, False) - f, gemm=True)
            self._unit_core = self._core(y)
        return self._unit_core
