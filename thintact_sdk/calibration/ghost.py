"""Ghosts: a faint, displaced copy of the whole sensor image.

A reflection between the mask and the sensor's cover glass (or inside the cover glass) adds
``g · S_d(Y)`` to every frame ``Y``: the same image, ``g`` times as bright (a few %), shifted
by ``d = (dy, dx)`` sensor pixels. It has two signatures, one for each way the two-term model
``Po X Qoᵀ + Pc X Qcᵀ`` reacts to it:

**Not separable** (``dy ≠ 0`` and ``dx ≠ 0``). A horizontal slit images as the rank-2
``Aᵢ = p_o q_oᵀ + p_c q_cᵀ`` with the same column profiles ``q`` for every slit; the ghost adds
``g (S_dy pᵢ)(S_dx q)ᵀ``. The solve (and the slits' own rank-2 fit) absorb what a common
change of ``q`` can explain — nearly all of the smooth open term's copy, whose left profile
barely moves — and the rest stays in the residual. :func:`slit_map` regresses every slit's
residual outside its two leading directions on exactly that rest, at every 2-D offset
``(dy, dx)`` at once (a least-squares fit per offset, both slit families and all channels
together), so the offset is found in 2-D and the strength is the whole ``g``, not a share of
its energy along one axis. The compressed slits (rank ``k``) lose part of a ghost that lies
below one frame's noise, so the best offset's strength is measured again on the full frames
(:func:`exact_strength`).

**Separable** (``dy = 0`` or ``dx = 0``). ``Y + g Y S_cᵀ = Po X Qoᵀ(I + gS_c)ᵀ + …`` is
exactly a two-term model: the solve absorbs it into ``Q`` (or ``P``), no residual is left and
validation scenes barely suffer at the design's own scale, but every reconstruction then
carries it. It shows as an echo in the calibrated coding matrix against the design's (direct
generation of the profile's φ at the unit's fitted pose, :func:`fit_pose`):
``Qc ≈ a X + b S_l X`` plus what is left of the pose error (the second-order expansion of an
affine misregistration of the shadow, :func:`_pose_terms`); ``g = b / a`` at the best lag.

On both, an offset counts only beyond :data:`MIN_LAG_CELLS` mask-shadow cells along each of
its non-zero axes (closer copies are blur, and there the design's pose error lives) and a
ghost is reported from :data:`MIN_STRENGTH` (a slit-map candidate must also stand
:data:`ROBUST_SIGMAS` robust standard deviations above the map's median).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np

from thintact_sdk.calibration.slits import ChannelSlits, SlitStack
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.host.blas import blas_threads
from thintact_sdk.reconstruction.direct_generation import AxisGeometry, DirectGenerator
from thintact_sdk.reconstruction.t2s import SystemMatrices

MIN_LAG_CELLS = 2.0
"""Smallest offset searched, in mask-shadow cells (feature × (z + d) / z on the sensor)."""
MAX_LAG_FRACTION = 0.25
"""Largest offset searched, as a fraction of the sensor's rows (columns)."""
MIN_STRENGTH = 0.025
"""A ghost fainter than 2.5 % of the image is not reported: a 3 % ghost read 20 % low still is
(on the healthy and dust/dim-column test units the echo scans' strongest candidates stayed
at 0.1-0.3 % against the design at the fitted pose (1.0-1.7 % at the profile's pose, 3.2 % on a
healthy 256 × 320 unit: issue 12), the slit map's at 0.1-0.2 %)."""
ROBUST_SIGMAS = 3.5
"""…and a slit-map candidate must stand this many robust standard deviations above the map's
median (the echo scans have too few lags on a small sensor for a robust spread: there a 5 %
ghost stood 2.4 robust σ out, a healthy unit's model error 1.9)."""
REFINE_FROM = 1.0 / 3.0
"""A slit-map candidate from this fraction of :data:`MIN_STRENGTH` up (and robust) gets its
exact strength from the full frames (the compressed slits read low)."""


@dataclass
class GhostScan:
    """One axis's scan: the strength a ghost at each lag would have.

    Attributes
    ----------
    name
        ``rows (vertical slits)``, ``columns (horizontal slits)``, ``rows (Pc echo)``,
        ``columns (Qc echo)``.
    lags
        Offsets tried (sensor pixels, signed).
    strength
        Estimated ghost brightness relative to the image at each lag.
    lag, value, significant
        The best lag, its strength and whether it passes both thresholds.
    estimate
        The ghost's brightness at ``lag`` (relative to the image; ``value`` unless the scan
        measures something smaller, such as the part above the other lags).
    """

    name: str
    lags: list[int]
    strength: list[float]
    lag: int = 0
    value: float = 0.0
    significant: bool = False
    estimate: float = float("nan")

    def decide(self, robust: bool = True) -> GhostScan:
        """Set ``lag``, ``value`` and ``significant`` (at least :data:`MIN_STRENGTH` and,
        when ``robust``, :data:`ROBUST_SIGMAS` robust standard deviations above the median
        of the scan)."""
        v = np.asarray(self.strength, np.float64)
        if v.size == 0:
            return self
        k = int(np.argmax(v))
        med = float(np.median(v))
        spread = 1.4826 * float(np.median(np.abs(v - med))) + 1e-300
        self.lag, self.value = int(self.lags[k]), float(v[k])
        self.estimate = self.value
        self.significant = bool(self.value >= MIN_STRENGTH and (not robust or v[k] - med >= ROBUST_SIGMAS * spread))
        return self


def _shift(x: np.ndarray, lag: int, axis: int = 0) -> np.ndarray:
    """``x`` moved by ``lag`` along ``axis``, zeros shifted in."""
    out = np.zeros_like(x)
    n = x.shape[axis]
    if abs(lag) >= n:
        return out
    dst = [slice(None)] * x.ndim
    src = [slice(None)] * x.ndim
    dst[axis] = slice(max(lag, 0), n + min(lag, 0))
    src[axis] = slice(max(-lag, 0), n - max(lag, 0))
    out[tuple(dst)] = x[tuple(src)]
    return out


def _lags(n: int, cell_px: float) -> list[int]:
    lo = max(1, int(np.ceil(MIN_LAG_CELLS * cell_px)))
    hi = max(lo, int(MAX_LAG_FRACTION * n))
    return [lag for lag in range(-hi, hi + 1) if abs(lag) >= lo]


def _gram2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``Σᵢ aᵢᵀ bᵢ`` over ``n × A × 2`` stacks (``2 × 2``)."""
    return np.asarray(np.tensordot(a, b, axes=([0, 1], [0, 1])))


def _signature(lead: np.ndarray, lag: int, keep: np.ndarray, lead_gram: np.ndarray | None = None) -> np.ndarray:
    """The left factors of a ghost's predictor at ``lag``: the slits' ``Yᵢ V`` (``n × A × 2``)
    shifted, less what a common change of ``V`` absorbs (a smooth open profile barely moves
    when shifted, so its copy is separable and the fit of ``V`` takes it): the tangent
    directions of the rank-2 fit are projected out, leaving what stays in the residual."""
    moved = _shift(lead, lag, axis=1) * keep[None, :, None]
    gram = _gram2(lead, lead) if lead_gram is None else lead_gram
    mix = np.linalg.solve(gram + 1e-300 * np.eye(2), _gram2(lead, moved))
    return np.asarray(moved - lead @ mix)


def _in_factor(vec: np.ndarray, lag: int, keep: np.ndarray) -> np.ndarray:
    """``P⊥ S_lag V`` on the kept lines (``B × 2``): the predictor's right factor."""
    w = _shift(vec, lag)
    return np.asarray((w - vec @ (vec.T @ w)) * keep[:, None])


def _correlate(u: np.ndarray, v: np.ndarray, lags: list[int], total: bool = False) -> np.ndarray:
    """``Σ_r u[:, r, :]ᵀ v[:, r − lag, :]`` for every lag, by FFT along axis 1 (zero padded,
    so no wrap-around): ``u`` is ``n × A × p``, ``v`` ``n × A × q``; ``L × n × p × q``, or
    ``L × p × q`` summed over ``n`` when ``total``."""
    size = 1 << int(np.ceil(np.log2(2 * u.shape[1])))
    fu = np.fft.rfft(u, size, axis=1)
    fv = np.conj(np.fft.rfft(v, size, axis=1))
    prod = np.einsum("nfp,nfq->fpq", fu, fv) if total else fu[..., :, None] * fv[..., None, :]
    c = np.fft.irfft(prod, size, axis=0 if total else 1)
    idx = np.asarray(lags, np.int64) % size
    return np.asarray(c[idx] if total else np.moveaxis(c[:, idx], 1, 0))


def _out_factors(left: np.ndarray, lead: np.ndarray, lags: list[int],
                 keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every lag ``a``: ``Lᵢᵀ sigᵢ(a)`` (``L × n × k × 2``) and ``Σᵢ sigᵢ(a)ᵀ sigᵢ(a)``
    (``L × 2 × 2``) with ``sig`` = :func:`_signature`, all lags at once by cross-correlation
    (the same numbers as shifting ``lead`` once per lag, which cost a minute per channel at
    the paper's size)."""
    kept = keep[None, :, None]
    gram = _gram2(lead, lead)
    cross = _correlate(lead * kept, lead, lags, total=True)  # Σ leadᵀ (keep·S_a lead)
    rows = np.einsum("naq,nar->aqr", lead, lead)  # per sensor line, A × 2 × 2
    size = 1 << int(np.ceil(np.log2(2 * len(keep))))
    moved_gram = np.fft.irfft(np.fft.rfft(keep, size)[:, None, None]
                              * np.conj(np.fft.rfft(rows, size, axis=0)), size, axis=0)
    moved_gram = moved_gram[np.asarray(lags, np.int64) % size]  # Σ (keep·S_a lead)ᵀ(keep·S_a lead)
    mix = np.linalg.solve(gram + 1e-300 * np.eye(2), cross)  # L × 2 × 2
    x = _correlate(left * kept, lead, lags) - np.matmul(left.transpose(0, 2, 1), lead)[None] @ mix[:, None]
    mct = np.matmul(mix.transpose(0, 2, 1), cross)
    gram_out = moved_gram - mct - mct.transpose(0, 2, 1) + mix.transpose(0, 2, 1) @ gram @ mix
    return x, gram_out


def _family_map(stack: SlitStack, out_lags: list[int], in_lags: list[int], keep_out: np.ndarray,
                keep_in: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normal equations of ``g`` at every ``(out lag, in lag)`` for one slit family.

    Each slit is ``Yᵢ ≈ Lᵢ Rᵢᵀ`` (``A × B``, compressed). With ``V`` (``B × 2``) the family's
    two leading directions along ``B`` and ``P⊥ = I − VVᵀ``, the part a ghost at ``(a, b)``
    leaves outside them is ``g · S_a (Yᵢ V)(P⊥ S_b V)ᵀ``; it is regressed on ``Yᵢ P⊥``.

    Returns
    -------
    (num, den, vec)
        ``Σᵢ ⟨Yᵢ P⊥, predictorᵢ⟩`` and ``Σᵢ ‖predictorᵢ‖²`` (``len(out_lags) × len(in_lags)``,
        DN²): ``g = num / den``; and ``V``.
    """
    left = stack.left * keep_out[None, :, None]  # n × A × k
    right = stack.right * keep_in[None, :, None]  # n × B × k
    n, _, k = left.shape
    b_len = right.shape[1]
    chol = np.linalg.cholesky(np.matmul(left.transpose(0, 2, 1), left) + 1e-12 * np.eye(k))
    factors = np.matmul(right, chol).transpose(1, 0, 2).reshape(b_len, n * k)  # Σ YᵢᵀYᵢ = F Fᵀ
    vec = np.linalg.svd(factors, full_matrices=False)[0][:, :2]  # B × 2
    rt = right.transpose(0, 2, 1)  # n × k × B
    lead = np.matmul(left, rt @ vec)  # Yᵢ V, n × A × 2
    perp = (rt - (rt @ vec) @ vec.T).reshape(n * k, b_len)  # (P⊥ Rᵢ)ᵀ, stacked
    x, gram_out = _out_factors(left, lead, out_lags, keep_out)
    w_all = np.stack([_in_factor(vec, b, keep_in) for b in in_lags])  # Lb × B × 2
    z = (perp @ w_all.transpose(1, 0, 2).reshape(b_len, -1)).reshape(n, k, len(in_lags), 2)
    num = x.reshape(len(out_lags), -1) @ z.transpose(2, 0, 1, 3).reshape(len(in_lags), -1).T
    den = np.einsum("aqr,bqr->ab", gram_out, np.matmul(w_all.transpose(0, 2, 1), w_all))
    return num, den, vec


@dataclass
class GhostMap:
    """The slit frames' ghost search over every 2-D offset.

    Attributes
    ----------
    row_lags, col_lags
        Offsets tried (sensor pixels, signed).
    strength
        ``len(row_lags) × len(col_lags)``: the least-squares ghost brightness (relative to
        the image) at each offset.
    score
        The same fit's amplitude ``num / √den`` (DN): how much of the slits it explains.
    directions
        ``{(channel, horizontal): V}``: each family's two leading directions (``B × 2``).
    keep_rows, keep_cols
        The sensor lines used (located defects left out).
    """

    row_lags: list[int]
    col_lags: list[int]
    strength: np.ndarray
    score: np.ndarray
    directions: dict[tuple[int, bool], np.ndarray]
    keep_rows: np.ndarray
    keep_cols: np.ndarray

    def robust(self, dy: int, dx: int) -> bool:
        """Whether the score at ``(dy, dx)`` stands :data:`ROBUST_SIGMAS` robust standard
        deviations above the map's median."""
        med = float(np.median(self.score))
        spread = 1.4826 * float(np.median(np.abs(self.score - med))) + 1e-300
        return bool(self.score[self.row_lags.index(dy), self.col_lags.index(dx)] - med >= ROBUST_SIGMAS * spread)

    def best(self) -> tuple[int, int, float, bool]:
        """``(rows, cols, strength, significant)`` at the offset that explains the most
        (significant: the strength reaches :data:`MIN_STRENGTH` and the offset is
        :meth:`robust`)."""
        i, j = np.unravel_index(int(np.argmax(self.score)), self.score.shape)
        dy, dx, g = int(self.row_lags[i]), int(self.col_lags[j]), float(self.strength[i, j])
        return dy, dx, g, bool(g >= MIN_STRENGTH and self.robust(dy, dx))

    def scans(self) -> list[GhostScan]:
        """The map through its best offset, one line per axis (for the report)."""
        dy, dx, g, ok = self.best()
        i, j = self.row_lags.index(dy), self.col_lags.index(dx)
        out = []
        for name, lags, line, lag in ((f"rows (slit frames, at {dx:+d} columns)", self.row_lags,
                                       self.strength[:, j], dy),
                                      (f"columns (slit frames, at {dy:+d} rows)", self.col_lags,
                                       self.strength[i, :], dx)):
            out.append(GhostScan(name, list(lags), [float(v) for v in line], lag, g, ok, g))
        return out


def slit_map(slits: list[ChannelSlits], row_lags: list[int], col_lags: list[int],
             keep_rows: np.ndarray | None = None, keep_cols: np.ndarray | None = None) -> GhostMap:
    """Strength of a non-separable ghost at every offset ``(dy, dx)`` from the compressed slits.

    A horizontal slit images as ``Yᵢ = Aᵢ`` of rank 2 with the same two column profiles for
    every slit; a ghost adds ``g · S_dy Aᵢ S_dxᵀ``, whose part outside those profiles is
    ``g · S_dy (Yᵢ V)(P⊥ S_dx V)ᵀ`` to first order in ``g``. Regressing every slit's
    ``Yᵢ P⊥`` on that predictor gives ``g`` at ``(dy, dx)`` by least squares — the whole
    ghost, not the part of its energy along a few directions. The vertical slits (stored
    transposed) give the same with the axes swapped; their normal equations are added, over
    every channel, so both families and all channels weigh by how much they see.
    Lines where ``keep_rows`` / ``keep_cols`` are False (located defects) are left out.
    OpenBLAS is held at one thread meanwhile: the products are small, and on a busy host
    two threads only spin-wait for each other (many times slower).
    """
    with blas_threads(1):  # small products: threads only spin-wait on a busy machine
        return _slit_map(slits, row_lags, col_lags, keep_rows, keep_cols)


def _slit_map(slits: list[ChannelSlits], row_lags: list[int], col_lags: list[int],
              keep_rows: np.ndarray | None, keep_cols: np.ndarray | None) -> GhostMap:
    r, s = slits[0].horizontal.out_len, slits[0].horizontal.in_len
    kr = np.ones(r, bool) if keep_rows is None else np.asarray(keep_rows, bool)
    kc = np.ones(s, bool) if keep_cols is None else np.asarray(keep_cols, bool)
    kr_f, kc_f = kr.astype(np.float64), kc.astype(np.float64)
    num = np.zeros((len(row_lags), len(col_lags)))
    den = np.zeros_like(num)
    directions = {}
    for c, ch in enumerate(slits):
        nh, dh, directions[c, True] = _family_map(ch.horizontal, row_lags, col_lags, kr_f, kc_f)
        nv, dv, directions[c, False] = _family_map(ch.vertical, col_lags, row_lags, kc_f, kr_f)
        num += nh + nv.T
        den += dh + dv.T
    den = np.maximum(den, 1e-300)
    return GhostMap(list(row_lags), list(col_lags), num / den, num / np.sqrt(den), directions, kr_f, kc_f)


def exact_strength(gmap: GhostMap, frames: Iterable[tuple[np.ndarray, bool]], dy: int, dx: int) -> float:
    """The ghost's strength at ``(dy, dx)`` from the full slit frames.

    The compressed slits keep each frame's leading ``k`` singular triplets; a ghost of a few
    % lies below a single frame's noise there, so truncation drops part of it and the map
    reads low (5 % read 3.6 % with k = 8). This is the same least-squares fit at one offset on
    the whole frames (``frames``: ``(R × S × C signal, horizontal slit?)``, DN above dark),
    with the map's leading directions.
    """
    acc: dict[tuple[int, bool], tuple[list[np.ndarray], list[np.ndarray]]] = {}
    for signal, horizontal in frames:
        for c in range(signal.shape[2]):
            vec = gmap.directions.get((c, horizontal))
            if vec is None:
                continue
            ka, kb = (gmap.keep_rows, gmap.keep_cols) if horizontal else (gmap.keep_cols, gmap.keep_rows)
            y = np.asarray(signal[..., c] if horizontal else signal[..., c].T, np.float64)
            y = ka[:, None] * y * kb[None, :]
            w = _in_factor(vec, dx if horizontal else dy, kb)
            m = y @ vec
            ms, ns = acc.setdefault((c, horizontal), ([], []))
            ms.append(m)
            ns.append(y @ w - m @ (vec.T @ w))  # Yᵢ P⊥ W
    num = den = 0.0
    for (c, horizontal), (ms, ns) in acc.items():
        vec = gmap.directions[c, horizontal]
        ka, kb = (gmap.keep_rows, gmap.keep_cols) if horizontal else (gmap.keep_cols, gmap.keep_rows)
        w = _in_factor(vec, dx if horizontal else dy, kb)
        z = _signature(np.stack(ms), dy if horizontal else dx, ka)
        num += float(np.sum(z * np.stack(ns)))
        den += float(np.sum(np.einsum("naq,nar->qr", z, z) * (w.T @ w)))
    return num / den if den > 0 else 0.0


MIN_DESIGN_SHARE = 0.5
"""The echo scans compare a calibrated coding matrix with the design's; they run only when the
design and its pose terms explain at least this share of the matrix's energy (healthy units:
0.9 and more; random matrices that are not the profile's design: far less, where ``b / a``
divided by a coefficient ``a`` near zero read ghosts of 497 814 %)."""


def _pose_terms(design: np.ndarray, design_open: np.ndarray) -> list[np.ndarray]:
    """The design and what its pose error adds, as the columns of the echo fit.

    The unit's mask shadow sits at ``u + δ(u, v)`` instead of ``u`` (sensor line ``u``, scene
    line ``v``, both centred), with ``δ = α + βu + γv`` affine: a shift, a scale error of the
    shadow (mask-to-sensor over scene-to-mask distance) and of the parallax (mask-to-sensor
    over scene-to-mask times the scene pitch). To second order the coding matrix changes by
    ``δ X' + ½ δ² X''``, i.e. by ``X'``, ``uX'``, ``vX'`` and ``X''`` times ``1, u, v, u²,
    uv, v²``; the open matrix by its level and ``u`` times it. The first-order terms alone
    fail with size: ``δ`` grows with the sensor, the left-over ``½ δ² X''`` with its square,
    and on a healthy 256 × 320 unit (distances 1.25 % and 1 % off the profile's) its
    correlation with the design shifted by 56 columns read as a 3.2 % ghost. The design is
    therefore generated at the fitted pose first (:func:`fit_pose`); these terms take what
    that leaves (the rotation, which a separable model cannot hold).
    """
    d1 = np.gradient(design, axis=0)
    d2 = np.gradient(d1, axis=0)
    u = (np.arange(design.shape[0]) - design.shape[0] / 2.0)[:, None]
    v = (np.arange(design.shape[1]) - design.shape[1] / 2.0)[None, :]
    u, v = u / max(1.0, float(np.abs(u).max())), v / max(1.0, float(np.abs(v).max()))
    return [design, d1, u * d1, v * d1, d2, u * d2, v * d2, u * u * d2, u * v * d2, v * v * d2,
            design_open, u * design_open]


def fit_pose(coding: np.ndarray, axis: AxisGeometry, vec: np.ndarray, keep: np.ndarray | None = None,
             iterations: int = 4) -> AxisGeometry:
    """The axis geometry whose direct generation fits the calibrated coding matrices best.

    ``coding`` (``C × lines × scene``) ≈ ``a X(θ) + c O(θ)`` (design and open matrix of the
    direct generator) is fitted by Gauss-Newton over θ = (mask-to-sensor distance, mask
    shift); the scene-to-mask distance stays (the shadow depends on the two distances
    through their ratio only). Steps are held to ±20 % of the distance and ±2 cells of
    shift: a unit further off is not this design. Matrices the profile's own design does not
    explain (:data:`MIN_DESIGN_SHARE`) keep the profile's geometry. Sensor lines where
    ``keep`` is False are left out.
    """
    w = np.ones((coding.shape[1], 1)) if keep is None else np.asarray(keep, np.float64).reshape(-1, 1)
    ys = np.stack([(np.asarray(c, np.float64) * w).ravel() for c in coding], axis=1)

    def residual(theta: np.ndarray) -> tuple[np.ndarray, float]:
        gen = DirectGenerator(replace(axis, d_mm=float(theta[0]), mask_shift_um=float(theta[1])))
        base = np.stack([(gen.coding(vec) * w).ravel(), (gen.open() * w).ravel()], axis=1)
        r = ys - base @ np.linalg.lstsq(base, ys, rcond=None)[0]
        return r.ravel(), 1.0 - float(np.sum(r * r)) / max(float(np.sum(ys * ys)), 1e-300)

    theta = np.array([axis.d_mm, axis.mask_shift_um])
    r0, share = residual(theta)
    if share < MIN_DESIGN_SHARE:
        return axis
    h = np.array([1e-3 * axis.d_mm, 0.05 * axis.sensor_pitch_um])
    lo = theta - np.array([0.2 * axis.d_mm, 2 * axis.feature_um])
    hi = theta + np.array([0.2 * axis.d_mm, 2 * axis.feature_um])
    for _ in range(iterations):
        jac = np.stack([(residual(theta + step_h * e)[0] - r0) / step_h for e, step_h in zip(np.eye(2), h, strict=True)],
                       axis=1)
        step = np.linalg.lstsq(jac, -r0, rcond=None)[0]
        trial = np.clip(theta + step, lo, hi)
        r1, share1 = residual(trial)
        if share1 <= share:  # no better: keep the last pose
            break
        theta, r0, share = trial, r1, share1
        if np.all(np.abs(step) < h):  # below the difference step: converged
            break
    return replace(axis, d_mm=float(theta[0]), mask_shift_um=float(theta[1]))


def echo_scan(coding: np.ndarray, design: np.ndarray, design_open: np.ndarray, lags: list[int],
              name: str, keep: np.ndarray | None = None) -> GhostScan:
    """Strength of a separable ghost at each lag: the calibrated coding matrices
    (``C × lines × scene``) against the design's, ``coding ≈ a X + b S_l X`` + the pose
    terms of :func:`_pose_terms`; ``g = b / a`` in the design's own units.

    A channel whose matrix the design does not explain (:data:`MIN_DESIGN_SHARE`) is not
    scanned; when none is, the scan has no lags and its name says why. Sensor lines where
    ``keep`` is False (located defects: a dim column or a dust shadow is in the matrix, not in
    the design) are left out of the fit.
    """
    w = np.ones((design.shape[0], 1)) if keep is None else np.asarray(keep, np.float64).reshape(-1, 1)
    base = np.stack([(m * w).ravel() for m in _pose_terms(design, design_open)], axis=1)
    base /= np.maximum(np.linalg.norm(base, axis=0), 1e-300)  # columns of one size: normal equations
    gram_b = base.T @ base
    scale_a = float(np.linalg.norm(design))
    ys, bys, shares = [], [], []
    for c in range(coding.shape[0]):
        y = (np.asarray(coding[c], np.float64) * w).ravel()
        by = base.T @ y
        coef = np.linalg.lstsq(gram_b, by, rcond=None)[0]
        share = float(coef @ by) / max(float(y @ y), 1e-300)  # explained energy, 0-1
        shares.append(share)
        if share >= MIN_DESIGN_SHARE and coef[0] != 0:  # a < 0: P and Q both flipped, allowed
            ys.append(y)
            bys.append(by)
    if not ys:
        return GhostScan(f"{name}: not scanned, the calibrated matrix does not follow the design "
                         f"(it explains {100 * max(shares, default=0.0):.0f} % of it)", [], []).decide()
    values = np.zeros(len(lags))
    for k, lag in enumerate(lags):  # one shifted design at a time (memory: one S × M array)
        sh = (_shift(design, lag) * w).ravel()
        norm = max(float(np.linalg.norm(sh)), 1e-300)
        col = sh / norm
        bs = base.T @ col
        a = np.block([[gram_b, bs[:, None]], [bs[None, :], np.array([[col @ col]])]])
        for y, by in zip(ys, bys, strict=True):
            coef = np.linalg.lstsq(a, np.append(by, col @ y), rcond=None)[0]
            # b/a in the design's own units: undo the two columns' normalisations (a is far
            # from 0: the design explains the matrix, checked above)
            values[k] += (coef[-1] / norm) / (coef[0] / scale_a) if coef[0] != 0 else 0.0
    return GhostScan(name, lags, [float(v) for v in values / len(ys)]).decide(robust=False)


@dataclass
class Ghost:
    """A ghost found: offset ``(rows, cols)`` in sensor pixels, strength, and how it shows."""

    rows: int
    cols: int
    strength: float
    separable: bool


def shadow_cell_px(profile: Profile) -> float:
    """A mask cell's shadow on the sensor, pixels: ``feature × (z + d) / z / pitch``."""
    geo = profile.geometry
    return profile.mask.feature_um * (geo.scene_to_mask_mm + geo.mask_to_sensor_mm) / (
        geo.scene_to_mask_mm * profile.sensor.pixel_pitch_um)


def find_ghosts(slits: list[ChannelSlits], sm: SystemMatrices, profile: Profile,
                keep_rows: np.ndarray | None = None, keep_cols: np.ndarray | None = None,
                frames: Iterable[tuple[np.ndarray, bool]] | None = None) -> tuple[list[Ghost], list[GhostScan]]:
    """Look for a ghost in the slit frames (non-separable) and the matrices (separable).

    ``slits`` are the compressed slits of every channel; ``keep_rows``, ``keep_cols``
    (boolean, per sensor row / column) leave the lines of defects already located out of the
    slit-frame search. ``frames`` (the full slit frames, ``(R × S × C signal, horizontal?)``)
    give a candidate's exact strength (:func:`exact_strength`).

    Returns
    -------
    (ghosts, scans)
        At most one ghost, and the four scans (for the report): the slit map through its
        best offset along each axis, and the two echo scans.
    """
    cell_px = shadow_cell_px(profile)
    r, s = sm.sensor_shape
    row_lags, col_lags = _lags(r, cell_px), _lags(s, cell_px)
    scans: list[GhostScan] = []
    ghosts: list[Ghost] = []
    if slits:
        gmap = slit_map(slits, row_lags, col_lags, keep_rows, keep_cols)
        dy, dx, g, ok = gmap.best()
        lines = gmap.scans()
        if frames is not None and g >= REFINE_FROM * MIN_STRENGTH and gmap.robust(dy, dx):
            with blas_threads(1):
                g = exact_strength(gmap, frames, dy, dx)
            ok = g >= MIN_STRENGTH
            for line in lines:
                line.estimate, line.significant = g, ok
        scans += lines
        if ok:
            ghosts.append(Ghost(dy, dx, g, separable=False))
    rows_vec, cols_vec = np.asarray(profile.mask.rows_vector, float), np.asarray(profile.mask.phi, float)
    # the echo fits leave located defects' lines out while at least half the lines stay (a
    # large dust speck's widened box can cover a small sensor's rows)
    kr, kc = (k if k is not None and float(np.mean(k)) >= 0.5 else None for k in (keep_rows, keep_cols))
    rows_gen = DirectGenerator(fit_pose(sm.Pc, AxisGeometry.rows_of(profile), rows_vec, kr))
    cols_gen = DirectGenerator(fit_pose(sm.Qc, AxisGeometry.cols_of(profile), cols_vec, kc))
    er = echo_scan(sm.Pc, rows_gen.coding(rows_vec), rows_gen.open(), row_lags, "rows (Pc echo)", kr)
    ec = echo_scan(sm.Qc, cols_gen.coding(cols_vec), cols_gen.open(), col_lags, "columns (Qc echo)", kc)
    scans += [er, ec]
    if not ghosts:
        best = max((sc for sc in (er, ec) if sc.significant), key=lambda sc: sc.value, default=None)
        if best is er:
            ghosts.append(Ghost(er.lag, 0, er.estimate, separable=True))
        elif best is ec:
            ghosts.append(Ghost(0, ec.lag, ec.estimate, separable=True))
    return ghosts, scans
