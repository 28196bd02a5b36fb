"""Ghosts: a faint, displaced copy of the whole sensor image.

A reflection between the mask and the sensor's cover glass (or inside the cover glass) adds
``g · S_d(Y)`` to every frame ``Y``: the same image, ``g`` times as bright (a few %), shifted
by ``d = (dy, dx)`` sensor pixels. It has two signatures, one for each way the two-term model
``Po X Qoᵀ + Pc X Qcᵀ`` reacts to it:

**Not separable** (``dy ≠ 0`` and ``dx ≠ 0``). A horizontal slit images as the rank-2
``p_o q_oᵀ + p_c q_cᵀ`` with the same column profiles ``q`` for every slit; the ghost adds
``g (S p)(S q)ᵀ``, so the column space of all horizontal slits grows from ``{q_o, q_c}`` to
also hold the shifted ``S_dx q``. For each lag ``l`` the energy of the slits (their Gram
matrix ``Σ YᵢᵀYᵢ``) along the shifted leading directions, beyond those directions and the
noise floor, measures ``g² ·`` the coding energy: ``g ≈ √(excess / λ₂)``. Vertical slits give
``dy`` the same way. The lag with the largest excess is the ghost's offset along that axis.

**Separable** (``dy = 0`` or ``dx = 0``). ``Y + g Y S_cᵀ = Po X Qoᵀ(I + gS_c)ᵀ + …`` is
exactly a two-term model: the solve absorbs it into ``Q`` (or ``P``), no residual is left and
validation scenes barely suffer at the design's own scale, but every reconstruction then
carries it. It shows as an echo in the calibrated coding matrix against the design's (direct
generation of the profile's φ): ``Qc ≈ a X + b S_l X`` plus nuisance directions for what the
pose and scale of the design may be off by (``X'``, ``u X'`` with ``u`` the sensor
coordinate, the open matrix and ``u`` times it); ``g = b / a`` at the best lag.

On both, a lag counts only beyond :data:`MIN_LAG_CELLS` mask-shadow cells (closer copies are
blur, and there the design's pose error lives) and a ghost is reported when its strength
exceeds both :data:`MIN_STRENGTH` and :data:`ROBUST_SIGMAS` robust standard deviations of
the scan over all lags.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from thintact_sdk.imaging.direct_generation import AxisGeometry, DirectGenerator
from thintact_sdk.imaging.t2s import SystemMatrices
from thintact_sdk.profile import Profile

MIN_LAG_CELLS = 2.0
"""Smallest offset searched, in mask-shadow cells (feature × (z + d) / z on the sensor)."""
MAX_LAG_FRACTION = 0.25
"""Largest offset searched, as a fraction of the sensor's rows (columns)."""
MIN_STRENGTH = 0.03
"""A ghost fainter than 3 % of the image is not reported (on the healthy and dust/dim-column
test units the scans' strongest candidates stayed below 1.8 %)."""
ROBUST_SIGMAS = 3.5
"""…and it must stand this many robust standard deviations above the scan's median."""


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


@dataclass
class SlitGrams:
    """Gram matrices of the slit frames (channel mean), accumulated one frame at a time.

    ``columns`` is ``Σ YᵢᵀYᵢ`` over horizontal slits (``S × S``), ``rows`` ``Σ YⱼYⱼᵀ`` over
    vertical slits (``R × R``), both in DN².
    """

    columns: np.ndarray
    rows: np.ndarray
    counts: list[int] = field(default_factory=lambda: [0, 0])

    @classmethod
    def empty(cls, shape: tuple[int, int]) -> SlitGrams:
        """Empty Grams for an ``R × S`` sensor."""
        return cls(np.zeros((shape[1], shape[1])), np.zeros((shape[0], shape[0])))

    def add(self, signal: np.ndarray, horizontal: bool) -> None:
        """Add one slit frame, ``R × S × C`` DN above dark."""
        y = np.asarray(signal, np.float64).mean(axis=2)
        if horizontal:
            self.columns += y.T @ y
            self.counts[0] += 1
        else:
            self.rows += y @ y.T
            self.counts[1] += 1


def _shift(x: np.ndarray, lag: int) -> np.ndarray:
    """``x`` moved by ``lag`` along axis 0, zeros shifted in."""
    out = np.zeros_like(x)
    if lag > 0:
        out[lag:] = x[:-lag]
    elif lag < 0:
        out[:lag] = x[-lag:]
    else:
        out[:] = x
    return out


def _lags(n: int, cell_px: float) -> list[int]:
    lo = max(1, int(np.ceil(MIN_LAG_CELLS * cell_px)))
    hi = max(lo, int(MAX_LAG_FRACTION * n))
    return [lag for lag in range(-hi, hi + 1) if abs(lag) >= lo]


def gram_scan(gram: np.ndarray, lags: list[int], name: str, keep: np.ndarray | None = None) -> GhostScan:
    """Strength of a non-separable ghost at each lag from a slit family's Gram matrix.

    The energy along the shifted two leading directions (orthogonalised to them) is taken
    above its median over all lags — noise, model error and local defects (a dust speck is
    not separable either) put energy there at every lag, a ghost at its own — relative to
    the coding energy ``λ₂``: ``g ≈ √(excess / λ₂)``. That finds the lag; the ghost's own
    brightness there is the energy above the noise floor (median eigenvalue per direction),
    as the ghost lifts the other lags too. Lines where ``keep`` is False (located
    defects: their residual energy would show at the lag that moves another feature onto
    them) are left out.
    """
    keep = np.ones(gram.shape[0], bool) if keep is None else np.asarray(keep, bool)
    gram = gram * np.outer(keep, keep)
    lam, vec = np.linalg.eigh(gram)
    lam, vec = lam[::-1], vec[:, ::-1]
    lead = vec[:, :2]
    captured = []
    for lag in lags:
        b = _shift(lead, lag) * keep[:, None]
        b -= lead @ (lead.T @ b)
        q, _ = np.linalg.qr(b)
        captured.append(float(np.trace(q.T @ gram @ q)))
    background = float(np.median(captured))
    coding = max(float(lam[1]), 1e-300)
    out = [float(np.sqrt(max(v - background, 0.0) / coding)) for v in captured]
    scan = GhostScan(name, lags, out).decide(robust=False)
    floor = float(np.median(lam[int(keep.sum()) // 4 : int(keep.sum())]))  # noise per direction
    scan.estimate = float(np.sqrt(max(captured[lags.index(scan.lag)] - 2.0 * floor, 0.0) / coding))
    return scan


def echo_scan(coding: np.ndarray, design: np.ndarray, design_open: np.ndarray, lags: list[int],
              name: str) -> GhostScan:
    """Strength of a separable ghost at each lag: the calibrated coding matrices
    (``C × lines × scene``) against the design's, ``coding ≈ a X + b S_l X`` + nuisance."""
    d = np.gradient(design, axis=0)
    u = (np.arange(design.shape[0]) - design.shape[0] / 2.0)[:, None]
    base = np.stack([m.ravel() for m in (design, d, u * d, design_open, u * design_open)], axis=1)
    base /= np.maximum(np.linalg.norm(base, axis=0), 1e-300)  # columns of one size: normal equations
    gram_b = base.T @ base
    scale_a = float(np.linalg.norm(design))
    ys = [np.asarray(coding[c], np.float64).ravel() for c in range(coding.shape[0])]
    bys = [base.T @ y for y in ys]
    values = np.zeros(len(lags))
    for k, lag in enumerate(lags):  # one shifted design at a time (memory: one S × M array)
        sh = _shift(design, lag).ravel()
        norm = max(float(np.linalg.norm(sh)), 1e-300)
        col = sh / norm
        bs = base.T @ col
        a = np.block([[gram_b, bs[:, None]], [bs[None, :], np.array([[col @ col]])]])
        for y, by in zip(ys, bys, strict=True):
            coef = np.linalg.lstsq(a, np.append(by, col @ y), rcond=None)[0]
            # b/a in the design's own units: undo the two columns' normalisations
            values[k] += (coef[-1] / norm) / (coef[0] / scale_a) if coef[0] != 0 else 0.0
    return GhostScan(name, lags, [float(v) for v in values / coding.shape[0]]).decide()


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


def find_ghosts(grams: SlitGrams, sm: SystemMatrices, profile: Profile,
                keep_rows: np.ndarray | None = None,
                keep_cols: np.ndarray | None = None) -> tuple[list[Ghost], list[GhostScan]]:
    """Look for a ghost in the slit frames (non-separable) and the matrices (separable).

    ``keep_rows``, ``keep_cols`` (boolean, per sensor row / column) leave the lines of
    defects already located out of the slit-frame scans.

    Returns
    -------
    (ghosts, scans)
        At most one ghost, and the four scans (for the report).
    """
    cell_px = shadow_cell_px(profile)
    r, s = sm.sensor_shape
    row_lags, col_lags = _lags(r, cell_px), _lags(s, cell_px)
    scans: list[GhostScan] = []
    if grams.counts[0] and grams.counts[1]:
        scans += [gram_scan(grams.rows, row_lags, "rows (vertical slits)", keep_rows),
                  gram_scan(grams.columns, col_lags, "columns (horizontal slits)", keep_cols)]
    rows_gen, cols_gen = DirectGenerator(AxisGeometry.rows_of(profile)), DirectGenerator(AxisGeometry.cols_of(profile))
    scans += [
        echo_scan(sm.Pc, rows_gen.coding(np.asarray(profile.mask.rows_vector, float)), rows_gen.open(),
                  row_lags, "rows (Pc echo)"),
        echo_scan(sm.Qc, cols_gen.coding(np.asarray(profile.mask.phi, float)), cols_gen.open(),
                  col_lags, "columns (Qc echo)"),
    ]
    by = {sc.name: sc for sc in scans}
    ghosts: list[Ghost] = []
    gr, gc = by.get("rows (vertical slits)"), by.get("columns (horizontal slits)")
    if gr is not None and gc is not None and gr.significant and gc.significant:
        ghosts.append(Ghost(gr.lag, gc.lag, 0.5 * (gr.estimate + gc.estimate), separable=False))
    else:
        er, ec = by["rows (Pc echo)"], by["columns (Qc echo)"]
        best = max((sc for sc in (er, ec) if sc.significant), key=lambda sc: sc.value, default=None)
        if best is er:
            ghosts.append(Ghost(er.lag, 0, er.estimate, separable=True))
        elif best is ec:
            ghosts.append(Ghost(0, ec.lag, ec.estimate, separable=True))
    return ghosts, scans
