"""Non-iterative solution of the *full* T2S Tikhonov problem (this SDK's extension).

``min ‖Po X Qoᵀ + Pc X Qcᵀ − Y‖² + τ‖X‖²`` has no closed form in general, but the open
matrices of a ThinTact are numerically low-rank (the open component is a smooth blur: the
singular values of Po, Qo fall by ~10⁴ within a handful). With ``Po ≈ Σ_i s_i u_i v_iᵀ``
(rank kp) and ``Qo`` (rank kq) the open operator ``Ao = Qo ⊗ Po = E Fᵀ`` has rank
``K = kp·kq`` (``E`` scaled sensor images, ``F`` orthonormal scene images), and

    AᵀA + τI = Hc + W Mmid Wᵀ,   Hc = QcᵀQc ⊗ PcᵀPc + τI,
    W = [F, G], G = AcᵀE,        Mmid = [[D, I], [I, 0]], D = EᵀE (diagonal)

so Woodbury's identity gives the exact minimiser with ``Hc⁻¹`` (diagonal in the SVD bases of
Pc, Qc, i.e. the coding-only closed form) plus a rank-2K correction::

    x0 = Hc⁻¹(Pcᵀ Y Qc) + Hc⁻¹F (Eᵀ Y)
    x  = x0 − Hc⁻¹W (Mmid⁻¹ + Wᵀ Hc⁻¹ W)⁻¹ Wᵀ x0

Per frame this is the coding-only closed form of the raw measurement (no joint filter), K
projections ``Eᵀ Y`` (folded into the same big product) and three thin ``NM × 2K`` products.
It is exact up to the truncation of Po, Qo (``open_rtol``), i.e. the limit iterative-800 tends to.

The truncation is done in the gauge where it drops least: the matrices as given or the
canonical gauge (``thintact_sdk.algorithms.canonical_gauge``: the same operator with the
smoothest open term). ``[Po Pc]·A``, ``[Qo Qc]·A⁻ᵀ`` describe the same device for any
invertible 2 × 2 ``A``; in the gauge the paper's Algorithms 1-3 land on,
``Po`` carries part of the coding term, its singular values fall only to 4 % by the 8th and
truncating there moved the PSNR by −0.02 … +0.17 dB on the calibration test recordings
(docs/calibration.md) — the decoder was then not the exact T2S solve it claims to be.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from thintact_sdk.calibration.gauge import canonical_gauge
from thintact_sdk.errors import InvalidShapeError
from thintact_sdk.reconstruction.decoders.backend import ArrayBackend, synthesis_macs
from thintact_sdk.reconstruction.decoders.closed_form_base import ClosedFormDecoder
from thintact_sdk.reconstruction.decoders.modes import (
    DEFAULT_MODE_RTOL,
    TauSpec,
    channel_taus,
    kept_mode_counts,
    representative_tau,
)
from thintact_sdk.reconstruction.first_order import largest_eigenvalue, nesterov
from thintact_sdk.reconstruction.scene_prior import ScenePrior
from thintact_sdk.reconstruction.t2s import SystemMatrices
from thintact_sdk.reconstruction.tikhonov import TikhonovSolver


def _truncated_svd(a: np.ndarray, rtol: float, max_rank: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    k = int(np.sum(s > rtol * s[0])) if s[0] > 0 else 1
    k = max(1, min(k, max_rank))
    return u[:, :k], s[:k], vt[:k].T


class T2SClosedFormDecoder(ClosedFormDecoder):
    """Exact (up to open-term truncation) full-T2S Tikhonov reconstruction, non-iterative.

    Parameters
    ----------
    system_matrices
        T2S matrices (DN per display unit); needs ``R ≥ N`` and ``S ≥ M``.
    tau
        Tikhonov weight τ (DN² units of the matrices).
    backend
        :class:`ArrayBackend` (default numpy float32).
    open_rtol, max_open_rank
        Singular values of Po, Qo kept: above ``open_rtol`` × the largest, at most
        ``max_open_rank`` per axis, after the matrices were put in the canonical gauge
        (the operator is unchanged). ``dropped_open_sv`` in :attr:`info` reports what was dropped.
    mode_rtol
        The coding term ``Σ_P U_Pᵀ Y U_Q Σ_Q`` (the two big products) is computed only for
        the Tikhonov modes whose filter factor reaches this
        (:func:`~thintact_sdk.reconstruction.decoders.modes.kept_mode_counts`); the rest of the solve keeps
        every mode. :attr:`kept_modes` says how many were kept.
    prior
        Generalised Tikhonov ``τ‖W_L X W_Rᵀ‖²`` instead of ``τ‖X‖²``
        (:class:`~thintact_sdk.algorithms.ScenePrior`; ``None`` or α = 0: plain). Solved
        exactly by the same closed form on ``P W_L⁻¹``, ``Q W_R⁻¹`` with ``W_L⁻¹``, ``W_R⁻ᵀ``
        folded into the final synthesis products: the per-frame cost is unchanged.
    """

    name = "t2s-closed-form"

    def __init__(
        self,
        system_matrices: SystemMatrices,
        tau: TauSpec,
        backend: ArrayBackend | None = None,
        open_rtol: float = 1e-6,
        max_open_rank: int = 8,
        mode_rtol: float = DEFAULT_MODE_RTOL,
        prior: ScenePrior | None = None,
    ) -> None:
        self.xp = backend or ArrayBackend("numpy")
        self.prior = None if prior is None or prior.is_plain else prior
        if self.prior is not None:
            system_matrices = self.prior.transform(system_matrices)
        sm, open_sv = _least_truncated(system_matrices, open_rtol, max_open_rank)
        (r, s), (n, m) = sm.sensor_shape, sm.scene_shape
        if r < n or s < m:
            raise InvalidShapeError("t2s-closed-form needs at least as many sensor rows/cols as scene rows/cols")
        # synthesis X = W_L⁻¹ (V_P ξ V_Qᵀ) W_R⁻ᵀ: the prior's inverse weights folded into V_P, V_Qᵀ
        out_left = np.eye(n) if self.prior is None else self.prior.inverse_weight(n)
        out_right_t = np.eye(m) if self.prior is None else self.prior.inverse_weight(m).T
        self.channels, self.sensor_shape, self.scene_shape = sm.channels, (r, s), (n, m)
        self.channel_tau = channel_taus(tau, sm.channels)
        self.tau = representative_tau(self.channel_tau)
        svds = []
        for c in range(sm.channels):
            up, sp, vpo = _truncated_svd(sm.Po[c].astype(np.float64), open_rtol, max_open_rank)
            uq, sq, vqo = _truncated_svd(sm.Qo[c].astype(np.float64), open_rtol, max_open_rank)
            svds.append((up, sp, vpo, uq, sq, vqo))
        kp = max(len(v[1]) for v in svds)
        kq = max(len(v[4]) for v in svds)
        self._kp, self._kq = kp, kq
        per: dict[str, list[np.ndarray]] = {key: [] for key in (
            "left", "up_t", "right", "sp", "sq", "den", "vp", "vqt", "uq", "scale", "a", "b", "a2", "b2", "small", "sig2")}
        self.info: dict[str, Any] = {"open_rank": [], "dropped_open_sv": []}
        self._parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self._grams: list[_GramFactors] = []  # τ-free factors of the small system, per channel
        for c in range(sm.channels):
            up, sp, vpo = _pad(*svds[c][:3], kp)
            uq, sq, vqo = _pad(*svds[c][3:], kq)
            sol = TikhonovSolver(sm.Pc[c], sm.Qc[c], float(self.channel_tau[c]), np.float64)
            # scene images of F and G expressed in the SVD bases of Pc, Qc (separable there)
            a, b = sol.vp.T @ vpo, sol.vqt @ vqo  # kP × kp, kQ × kq
            a2, b2 = (sol.left @ up) * sp, (sol.right.T @ uq) * sq  # Vpᵀ Pcᵀ u s, Vqᵀ Qcᵀ u s
            sig2 = np.outer(sol.singular_values_p**2, sol.singular_values_q**2)
            part = (np.concatenate([a, a2], 1), np.concatenate([b, b2], 1), np.outer(sp**2, sq**2), sig2)
            self._parts.append(part)
            self._grams.append(_GramFactors(part, kp, kq))
            per["small"].append(self._grams[c].small_inverse(float(self.channel_tau[c])))
            per["left"].append(sol.left)  # kP × R
            per["up_t"].append(up.T)  # kp × R
            per["right"].append(sol.right)
            per["sp"].append(sol.singular_values_p)
            per["sq"].append(sol.singular_values_q)
            per["den"].append(sol.inv_denom)
            per["sig2"].append(sig2)
            per["vp"].append(out_left @ sol.vp)
            per["vqt"].append(sol.vqt @ out_right_t)
            per["uq"].append(uq)
            per["scale"].append(np.outer(sp, sq))
            for key, val in (("a", a), ("b", b), ("a2", a2), ("b2", b2)):
                per[key].append(val)
            self.info["open_rank"].append([int(np.sum(sp > 0)), int(np.sum(sq > 0))])
            full_p, full_q = open_sv[c]
            self.info["dropped_open_sv"].append([_dropped_fraction(full_p, len(svds[c][1])),
                                                 _dropped_fraction(full_q, len(svds[c][4]))])
        xp = self.xp
        self.mode_rtol = float(mode_rtol)
        self._coding_left, self._up_t = np.stack(per["left"]), np.stack(per["up_t"])
        self._coding_right = np.stack(per["right"])
        self._sp, self._sq = np.stack(per["sp"]), np.stack(per["sq"])  # C × kP, C × kQ
        self._full_modes = (self._coding_left.shape[1], self._coding_right.shape[2])
        self._left_all: Any = None  # every coding mode and E's rows, placed by :meth:`project`
        self._right_all: Any = None  # every coding mode's columns, placed by :meth:`project`
        self.kept_modes = (0, 0)
        self._place(*kept_mode_counts(self._sp, self._sq, self.channel_tau, self.mode_rtol))
        self._uq = xp.asarray(np.stack(per["uq"]), gemm=True)  # C × S × kq
        st = {key: xp.asarray(np.stack(per[key]), gemm=key in ("vp", "vqt"))
              for key in ("den", "vp", "vqt", "scale", "a", "b", "a2", "b2", "small", "sig2")}
        self._den, self._vp, self._vqt, self._scale = st["den"], st["vp"], st["vqt"], st["scale"]
        self._a, self._b, self._a2, self._b2, self._small = st["a"], st["b"], st["a2"], st["b2"], st["small"]
        self._sig2 = st["sig2"]  # σ_P,i² σ_Q,j² of Pc, Qc
        # float64 copies for the per-τ constants of the frame solve (C × kP × 2kp, C × kQ × 2kq)
        self._a_all64 = np.concatenate([np.stack(per["a"]), np.stack(per["a2"])], axis=2)
        self._b_all64 = np.concatenate([np.stack(per["b"]), np.stack(per["b2"])], axis=2)
        self._scale64 = np.stack(per["scale"])
        self._a_all = xp.asarray(self._a_all64)
        self._b_all = xp.asarray(self._b_all64)
        self._refresh_frame_constants()

    def _place(self, kp: int, kq: int) -> None:
        """Put the big products' operators for the leading ``kp × kq`` coding modes (and the
        open term's ``E`` rows) on the backend, contiguous."""
        xp = self.xp
        self.kept_modes = (kp, kq)
        self.k_p = kp
        self._left = xp.asarray(np.concatenate([self._coding_left[:, :kp], self._up_t], axis=1), gemm=True)
        self._right = xp.asarray(self._coding_right[..., :kq], gemm=True)

    def gemm_flops(self) -> int:
        """Floating-point operations of the matrix products of one frame, all channels."""
        (r, s), (n, m) = self.sensor_shape, self.scene_shape
        (kp, kq), (big_p, big_q) = self.kept_modes, self._full_modes
        ko_p, ko_q = self._kp, self._kq
        big = (kp + ko_p) * r * s + kp * s * kq + ko_p * s * ko_q
        # a e bᵀ and the two correction terms (3×), the projections aᵀ ξ b and a2ᵀ ξ b2 (2×)
        woodbury = 3 * (big_p * ko_p * ko_q + big_p * ko_q * big_q) + 2 * (ko_p * big_p * big_q + ko_p * big_q * ko_q)
        return 2 * self.channels * (big + woodbury + synthesis_macs(n, big_p, big_q, m))

    def set_tau(self, tau: TauSpec) -> None:
        """Change τ (one value, or one per channel) without recomputing any SVD.

        Per channel the work is ``1/(σ² + τ)`` (elementwise, ``kP × kQ``), the 2K × 2K Gram
        ``Wᵀ Hc⁻¹ W`` as two matrix products with τ-free factors precomputed at construction
        (:class:`_GramFactors`), and the inverse of the 2K × 2K small system; the coding
        modes kept follow the new τ. Decoding after ``set_tau(τ)`` equals a decoder built at
        ``τ`` up to float rounding."""
        self.channel_tau = channel_taus(tau, self.channels)
        self.tau = representative_tau(self.channel_tau)
        kept = kept_mode_counts(self._sp, self._sq, self.channel_tau, self.mode_rtol)
        if kept != self.kept_modes:
            self._place(*kept)
        xp = self.xp
        taus = [float(t) for t in self.channel_tau]
        self._den = xp.asarray(np.stack([1.0 / (p[3] + t) for p, t in zip(self._parts, taus, strict=True)]))
        self._small = xp.asarray(np.stack([g.small_inverse(t) for g, t in zip(self._grams, taus, strict=True)]))
        self._refresh_frame_constants()

    def _refresh_frame_constants(self) -> None:
        """Precompute what the frame solve needs for the current τ and kept modes.

        * ``_coef_e`` (``C × 2K × K``): the small system's answer to the open term's own share
          ``Hc⁻¹ (a E bᵀ)`` as a linear map of ``vec(E)``, so that share is never formed at
          full size.
        * The black level: a uniform frame is rank one through the big products
          (``core = p qᵀ``, ``E = E₁``), so a pedestal ``b`` is ``b·E₁`` off ``E``, one more
          rank-one term of the correction (``_lr_left``/``_lr_right_t`` end in ``p``/``q``) and a
          constant vector ``_black_coef`` of the small system: no unit image is decoded and no full-size pass
          is spent on it. ``p``, ``q``, ``E₁`` come from the operators in GEMM precision, so
          the pedestal cancels through the products' own rounding.
        """
        xp = self.xp
        kp, kq = self._kp, self._kq
        k = kp * kq
        left = np.asarray(xp.to_numpy(self._left), np.float64)  # C × (kept + kp) × R
        right = np.asarray(xp.to_numpy(self._right), np.float64)  # C × S × kept
        uq = np.asarray(xp.to_numpy(self._uq), np.float64)  # C × S × kq
        den = np.asarray(xp.to_numpy(self._den), np.float64)
        small = np.asarray(xp.to_numpy(self._small), np.float64)
        (full_p, full_q), kept = self._full_modes, self.k_p
        p = np.zeros((self.channels, full_p))
        p[:, :kept] = left[:, :kept].sum(axis=2)
        q = np.zeros((self.channels, full_q))
        q[:, : right.shape[2]] = right.sum(axis=1)
        e1 = np.einsum("ci,cj->cij", left[:, kept:].sum(axis=2), uq.sum(axis=1)) * self._scale64
        coef_e, black_coef = [], []
        for c in range(self.channels):
            a_all, b_all = self._a_all64[c], self._b_all64[c]
            # [aᵀ Z b; a2ᵀ Z b2] for Z = Hc⁻¹ (a_i b_jᵀ): the (i, j) column of the map, i.e. the
            # first K columns of the Gram Wᵀ Hc⁻¹ W the small system was inverted from
            cols = self._grams[c].last_gram[:, :k]
            zb = den[c] * np.outer(p[c], q[c])
            proj_b = np.concatenate([(a_all[:, :kp].T @ zb @ b_all[:, :kq]).ravel(),
                                     (a_all[:, kp:].T @ zb @ b_all[:, kq:]).ravel()])
            coef_e.append(small[c] @ cols)
            black_coef.append(small[c] @ proj_b)
        self._coef_e = xp.asarray(np.stack(coef_e))
        self._black_coef = xp.asarray(np.stack(black_coef)[..., None])  # C × 2K × 1
        self._e_unit = xp.asarray(e1)
        self._mid_zeros = xp.asarray(np.zeros((self.channels, 2 * kp + 1, 2 * kq + 1)))
        self._lr_left = xp.asarray(np.concatenate([self._a_all64, p[..., None]], axis=2))  # C × kP × (2kp+1)
        self._lr_right_t = xp.asarray(np.swapaxes(np.concatenate([self._b_all64, q[..., None]], axis=2), 1, 2))

    def project(self, frame: np.ndarray) -> tuple[Any, Any]:
        """The τ-free big products of ``frame`` (``R × S × C`` DN above black), for decoding it
        at several τ with :meth:`decode_projected`.

        Returns ``(core, E)``: ``Σ_P U_Pᵀ Y U_Q Σ_Q`` for every coding mode (``C × kP × kQ``)
        and the open term's ``E`` (``C × kp × kq``), both products in GEMM precision, stored in
        the backend's precision. Which coding modes a decode uses depends on τ
        (``mode_rtol``); it takes the leading block it needs, so a sweep over τ takes neither
        big product again.
        """
        self._check(frame)
        xp = self.xp
        if self._left_all is None:
            self._left_all = xp.asarray(np.concatenate([self._coding_left, self._up_t], axis=1), gemm=True)
            self._right_all = xp.asarray(self._coding_right, gemm=True)
        t = self._left_all @ xp.channels_first(frame, gemm=True)
        big_p = self._full_modes[0]
        core = xp.cast(t[:, :big_p] @ self._right_all, gemm=False)
        return core, xp.cast(t[:, big_p:] @ self._uq, gemm=False) * self._scale

    def decode_projected(self, projected: tuple[Any, Any]) -> np.ndarray:
        """:meth:`decode` of the frame :meth:`project` returned ``projected`` for, at the
        current τ (the same figures up to float rounding; black level 0; ``projected`` is
        not changed)."""
        core_all, e = projected
        kept_p, kept_q = self.k_p, self._right.shape[2]
        xp = self.xp
        if xp.name == "numpy" and xp.gemm_dtype == xp.dtype:
            core = np.zeros((self.channels, *self._full_modes), xp.dtype)
            core[:, :kept_p, :kept_q] = core_all[:, :kept_p, :kept_q]
            return self._solve_blocked_core(core, e, 0.0)
        kept = core_all[:, :kept_p, :kept_q]
        core = xp.pad_to(kept, *self._full_modes)
        if core is kept:  # every mode kept: the solve scales its core in place, so a copy
            core = kept * 1
        return self._solve_core(core, e, 0.0)

    def _linear(self, y: Any) -> tuple[Any, Any]:
        """``(Σ_P U_Pᵀ Y U_Q Σ_Q, Eᵀ Y)`` for channel-first ``y`` (GEMM precision)."""
        t = self._left @ y  # C × (kept kP + kp) × S
        return self._linear_projected(t[:, : self.k_p], t[:, self.k_p :])

    def _linear_projected(self, t_c: Any, t_o: Any) -> tuple[Any, Any]:
        """:meth:`_linear` from the first product's coding rows ``t_c`` (the kept modes) and
        open rows ``t_o``."""
        xp = self.xp
        core = xp.pad_to(xp.cast(t_c @ self._right, gemm=False), *self._full_modes)
        e = xp.cast(t_o @ self._uq, gemm=False) * self._scale  # C × kp × kq
        return core, e

    def _solve(self, y: Any, black_dn: float = 0.0) -> np.ndarray:
        t = self._left @ y  # C × (kept kP + kp) × S
        return self._solve_projected(t[:, : self.k_p], t[:, self.k_p :], black_dn)

    def _solve_projected(self, t_c: Any, t_o: Any, black_dn: float) -> np.ndarray:
        """One frame: ``ξ = Hc⁻¹ (core + a E bᵀ) − Hc⁻¹ W (…)⁻¹ Wᵀ(…)`` written as
        ``Hc⁻¹ ⊙ core + Hc⁻¹ ⊙ (A M Bᵀ)`` with one rank-(2kp+1) product ``A M Bᵀ``: four
        full-size passes between the big products (scale, project, add, scale) instead of
        a dozen; on numpy, fewer still (:meth:`_solve_blocked`)."""
        xp = self.xp
        if xp.name == "numpy" and xp.gemm_dtype == xp.dtype:
            return self._solve_blocked(t_c, t_o, black_dn)
        core, e = self._linear_projected(t_c, t_o)
        return self._solve_core(core, e, black_dn)

    def _solve_core(self, core: Any, e: Any, black_dn: float) -> np.ndarray:
        """:meth:`_solve_projected` from the coding core (``C × kP × kQ``, zero past the kept
        modes; this frame's own array, scaled in place) and ``E``."""
        xp = self.xp
        if black_dn:
            e = e - black_dn * self._e_unit
        core *= self._den  # Hc⁻¹ ⊙ core (core is this frame's own array)
        proj = xp.swap(self._a_all) @ core  # C × 2kp × kQ: reads the full array once
        mid = self._mid(proj, e, black_dn)
        low = self._lr_left @ mid @ self._lr_right_t  # C × kP × kQ
        low *= self._den
        core += low
        return xp.synthesise(self._vp, core, self._vqt)

    def _mid(self, proj: Any, e: Any, black_dn: float) -> Any:
        """The small system: ``proj = [a a2]ᵀ (Hc⁻¹ ⊙ core)`` and ``E`` → the ``(2kp+1) × (2kq+1)``
        middle factor of the correction ``A M Bᵀ``."""
        xp = self.xp
        c, k, kp, kq = proj.shape[0], self._kp * self._kq, self._kp, self._kq
        w = xp.contiguous(proj[:, :kp] @ self._b).reshape(c, k, 1)
        w2 = xp.contiguous(proj[:, kp:] @ self._b2).reshape(c, k, 1)
        coef = self._small @ xp.cat([w, w2], axis=1) + self._coef_e @ xp.contiguous(e).reshape(c, k, 1)
        if black_dn:
            coef = coef - black_dn * self._black_coef
        mid = xp.zeros_like(self._mid_zeros)
        mid[:, :kp, :kq] = e - xp.contiguous(coef[:, :k]).reshape(c, kp, kq)
        mid[:, kp : 2 * kp, kq : 2 * kq] = -xp.contiguous(coef[:, k:]).reshape(c, kp, kq)
        mid[:, 2 * kp, 2 * kq] = -black_dn
        return mid

    def _solve_blocked(self, t_c: np.ndarray, t_o: np.ndarray, black_dn: float) -> np.ndarray:
        """:meth:`_solve` on numpy with the full-size passes between the big products done in
        cache-sized blocks of coefficient rows: the second big product writes straight into
        the zero-padded coefficient array (no padding copy), each block is scaled by ``Hc⁻¹``
        and projected while in cache, and the correction ``A M Bᵀ`` is formed block by block,
        scaled and added without ever being written at full size. The same arithmetic up to
        float32 rounding; one read and one write of the coefficients fewer than the generic
        path, and no padding pass."""
        c = self.channels
        (big_p, big_q), kept_p = self._full_modes, self.k_p
        kept_q = self._right.shape[2]
        core = np.empty((c, big_p, big_q), self.xp.dtype)
        np.matmul(t_c, self._right, out=core[:, :kept_p, :kept_q])
        core[:, :kept_p, kept_q:] = 0
        core[:, kept_p:] = 0
        return self._solve_blocked_core(core, (t_o @ self._uq) * self._scale, black_dn)

    def _solve_blocked_core(self, core: np.ndarray, e: np.ndarray, black_dn: float) -> np.ndarray:
        """:meth:`_solve_blocked` from the coding core (``C × kP × kQ``, zero past the kept
        modes; this frame's own array, scaled in place) and ``E`` (``C × kp × kq``)."""
        c = self.channels
        (big_p, big_q), kept_p, kp = self._full_modes, self.k_p, self._kp
        if black_dn:
            e = e - black_dn * self._e_unit
        den, a_all = self._den, self._a_all
        step = _block_rows(c, big_q, core.itemsize)
        proj = np.zeros((c, 2 * kp, big_q), core.dtype)
        for lo in range(0, kept_p, step):  # rows past kept_p are zero: nothing to project
            blk = core[:, lo : lo + step]
            blk *= den[:, lo : lo + step]
            proj += a_all[:, lo : lo + step].swapaxes(1, 2) @ blk
        right = self._mid(proj, e, black_dn) @ self._lr_right_t  # C × (2kp+1) × kQ
        low = np.empty((c, step, big_q), core.dtype)
        for lo in range(0, big_p, step):
            rows = min(step, big_p - lo)
            part = np.matmul(self._lr_left[:, lo : lo + rows], right, out=low[:, :rows])
            part *= den[:, lo : lo + rows]
            core[:, lo : lo + rows] += part
        return self.xp.synthesise(self._vp, core, self._vqt)

    def _normal_op(self, xi: Any) -> Any:
        """``AᵀA`` in SVD coefficients: ``(σ_P² σ_Qᵀ²) ⊙ ξ + W Mmid Wᵀ ξ`` (τ excluded)."""
        xp = self.xp
        a, b, a2, b2 = self._a, self._b, self._a2, self._b2
        wf = xp.swap(a) @ xi @ b
        wg = xp.swap(a2) @ xi @ b2
        d = self._scale * self._scale  # D = s_p² s_q² as kp × kq
        out = self._sig2 * xi + a @ (d * wf + wg) @ xp.swap(b) + a2 @ wf @ xp.swap(b2)
        return out

    def iterate(self, signal: np.ndarray, iterations: int = 800, power_iterations: int = 100) -> np.ndarray:
        """Nesterov's accelerated gradient (step ``1/L``) on the same objective, run in this
        decoder's coordinates: the iterates of the iterative T2S baseline (up to the open-term
        truncation) at a tiny cost per iteration. For checking iterative baselines; ``decode``
        gives the limit they converge to.
        """
        self._check(signal)
        xp = self.xp
        core, e = self._linear(xp.channels_first(signal, gemm=True))
        rhs = core + self._a @ e @ xp.swap(self._b)  # Aᵀ y in coefficients
        start = xp.asarray(np.random.default_rng(0).standard_normal(tuple(rhs.shape)))
        lam = largest_eigenvalue(self._normal_op, start, power_iterations, xp.sum_squares)
        step = 1.0 / (2.0 * (lam * 1.02 + float(self.channel_tau.max())))
        tau = xp.asarray(self.channel_tau[:, None, None])

        def gradient(z: Any) -> Any:
            return 2.0 * (self._normal_op(z) - rhs) + (2.0 * tau) * z

        x = nesterov(gradient, xp.zeros_like(rhs), step, iterations)
        return xp.synthesise(self._vp, x, self._vqt)


BLOCK_BYTES = 1 << 18
"""Size of one block of coefficient rows in :meth:`T2SClosedFormDecoder._solve_blocked`
(all channels): 256 KiB, well inside a core's L2 cache next to its correction block."""


def _block_rows(channels: int, cols: int, itemsize: int) -> int:
    """Coefficient rows per cache block (at least 8)."""
    return max(8, BLOCK_BYTES // (channels * cols * itemsize))


def _truncation_loss(sm: SystemMatrices, rtol: float, max_rank: int) -> tuple[float, list[list[np.ndarray]]]:
    """Largest share of squared singular values of Po or Qo (any channel) the truncation
    drops, and those singular values (``[[Po's, Qo's] per channel]``)."""
    worst = 0.0
    values: list[list[np.ndarray]] = []
    for c in range(sm.channels):
        values.append([])
        for a in (sm.Po[c], sm.Qo[c]):
            sv = np.linalg.svd(np.asarray(a, np.float64), compute_uv=False)
            values[-1].append(sv)
            sv2 = sv**2
            if sv2[0] <= 0:
                continue
            kept = max(1, min(int(np.sum(sv2 > rtol**2 * sv2[0])), max_rank))
            worst = max(worst, float(sv2[kept:].sum() / sv2.sum()))
    return worst, values


def _least_truncated(sm: SystemMatrices, rtol: float, max_rank: int) -> tuple[SystemMatrices, list[list[np.ndarray]]]:
    """``sm`` as given or in the canonical gauge, whichever loses less to the truncation of
    its open term (the operator is the same), and the singular values of its Po, Qo per
    channel (:func:`_truncation_loss`)."""
    canonical = canonical_gauge(sm)
    loss_canonical, values_canonical = _truncation_loss(canonical, rtol, max_rank)
    loss, values = _truncation_loss(sm, rtol, max_rank)
    if loss_canonical < loss:
        return canonical, values_canonical
    return sm, values


def _dropped_fraction(sv: np.ndarray, kept: int) -> float:
    """Largest dropped singular value relative to the largest; 0 for an all-zero (one-term,
    coding-only) open matrix."""
    return float(sv[kept:].max(initial=0) / sv[0]) if sv[0] > 0 else 0.0


class _GramFactors:
    """The τ-free factors of one channel's small system ``(Mmid⁻¹ + Wᵀ Hc⁻¹ W)⁻¹``.

    In the SVD bases of Pc, Qc, ``Hc⁻¹ = 1/(σ_P² σ_Qᵀ² + τ)`` is diagonal (``kP × kQ``) and
    the columns of ``W`` are separable, ``ω_ij = a_i b_jᵀ``, so the Gram entry
    ``⟨ω_ij, Hc⁻¹ ω_kl⟩ = Σ_ab a_ai a_ak Hc⁻¹_ab b_bj b_bl``. Its τ-free factors — the
    products ``a_i ⊙ a_k`` (``kP × 4kp²``) and ``b_j ⊙ b_l`` (``kQ × 4kq²``) of the column
    pairs the four blocks of the Gram use — are formed once; for each τ the Gram is two
    matrix products ``(a⊙a)ᵀ Hc⁻¹ (b⊙b)`` (``O(kP·kQ·4kp² + kp²·kQ·4kq²)``) instead of an
    ``einsum`` over the five indices, and the 2K × 2K inverse follows. ``Hc⁻¹`` is not
    diagonal in any small basis of ``W``, so the sum over the ``kP × kQ`` modes stays.

    ``part = (A_all: kP × 2kp, B_all: kQ × 2kq, D: kp × kq, σ²: kP × kQ)``.
    """

    def __init__(self, part: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], kp: int, kq: int) -> None:
        a_all, b_all, d, sig2 = part
        self.kp, self.kq, self.sig2 = kp, kq, sig2
        a_f, a_g, b_f, b_g = a_all[:, :kp], a_all[:, kp:], b_all[:, :kq], b_all[:, kq:]
        # rows: (i, k) pairs of the blocks FF, FG, GF, GG; each kp² (resp. kq²) long
        self._aa = np.concatenate([np.einsum("ai,ak->ika", x, y).reshape(kp * kp, -1)
                                   for x, y in ((a_f, a_f), (a_f, a_g), (a_g, a_f), (a_g, a_g))])
        self._bb = [np.einsum("bj,bl->bjl", x, y).reshape(-1, kq * kq)
                    for x, y in ((b_f, b_f), (b_f, b_g), (b_g, b_f), (b_g, b_g))]
        k = kp * kq
        eye = np.eye(k)
        self._mmid_inv = np.block([[np.zeros((k, k)), eye], [eye, -np.diag(d.ravel())]])
        self.last_gram = np.zeros((2 * k, 2 * k))

    def gram(self, tau: float) -> np.ndarray:
        """``Wᵀ Hc⁻¹ W`` (2K × 2K, float64) at ``τ``."""
        kp, kq, k = self.kp, self.kq, self.kp * self.kq
        x = self._aa @ (1.0 / (self.sig2 + tau))  # 4kp² × kQ
        blocks = []
        for n, bb in enumerate(self._bb):
            t = x[n * kp * kp : (n + 1) * kp * kp] @ bb  # (i k) × (j l)
            blocks.append(t.reshape(kp, kp, kq, kq).transpose(0, 2, 1, 3).reshape(k, k))
        return np.block([[blocks[0], blocks[1]], [blocks[2], blocks[3]]])

    def small_inverse(self, tau: float) -> np.ndarray:
        """``(Mmid⁻¹ + Wᵀ Hc⁻¹ W)⁻¹`` at ``τ``; the Gram is kept in :attr:`last_gram`."""
        self.last_gram = self.gram(tau)
        return np.asarray(np.linalg.inv(self._mmid_inv + self.last_gram))


def _pad(u: np.ndarray, s: np.ndarray, v: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    extra = k - len(s)
    if extra <= 0:
        return u, s, v
    return (np.pad(u, ((0, 0), (0, extra))), np.pad(s, (0, extra)), np.pad(v, ((0, 0), (0, extra))))
